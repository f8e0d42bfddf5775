"""Without the optional extra ``cluster`` (Dask, Optuna): a one-line error that names it, exit 2."""

from __future__ import annotations

import importlib

import pytest
from helpers import write_otb

from covviz.cli import main


@pytest.fixture
def without_extra(monkeypatch):
    real = importlib.import_module

    def fake(name, *a, **k):
        if name.split(".")[0] in ("dask", "distributed", "optuna"):
            raise ImportError(f"No module named {name!r}")
        return real(name, *a, **k)

    monkeypatch.setattr("covviz.experiments.cluster.importlib.import_module", fake)


@pytest.mark.parametrize("command", ["bench", "tune"])
def test_a_missing_extra_is_named_in_one_line(command, without_extra, tmp_path, capsys):
    write_otb(tmp_path / "seq" / "alpha", 4, seed=1)
    argv = [command, str(tmp_path / "seq"), "--out", str(tmp_path / "out"), "--no-progress"]
    argv += ["--cluster", "local:2", "--trackers", "identity"] if command == "bench" else ["--trials", "1"]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "optional extra 'cluster'" in err[0] and "pip install 'covviz[cluster]'" in err[0]
