"""Architecture rules of covviz, checked on the source (STYLE.md: data flow, randomness passed in).

* Only ``covviz/viz/`` and ``covviz/cli.py`` import ``rerun``: the tracker core
  knows nothing of the instrumentation.
* No global numpy randomness anywhere in the package (``np.random.seed``,
  ``np.random.rand`` …): every stochastic function takes an ``rng``.
* The core modules import without pulling ``rerun`` into ``sys.modules``
  (checked in a fresh interpreter).
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import covviz

PACKAGE = Path(covviz.__file__).resolve().parent
SOURCES = sorted(PACKAGE.rglob("*.py"))

# Constructors of explicit generators: the only numpy.random names the package may use.
ALLOWED_NP_RANDOM = {
    "default_rng",
    "Generator",
    "SeedSequence",
    "BitGenerator",
    "PCG64",
    "PCG64DXSM",
    "Philox",
    "SFC64",
    "MT19937",
}


def rel(path: Path) -> str:
    return path.relative_to(PACKAGE.parent).as_posix()


def parse(path: Path) -> ast.Module:
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def may_import_rerun(path: Path) -> bool:
    r = rel(path)
    return r.startswith("covviz/viz/") or r == "covviz/cli.py"


def rerun_imports(tree: ast.Module) -> list[int]:
    """Line numbers of ``import rerun…``, ``from rerun… import``, ``importlib.import_module("rerun…")``."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            if any(a.name == "rerun" or a.name.startswith("rerun.") for a in node.names):
                lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0 and node.module and (node.module == "rerun" or node.module.startswith("rerun.")):
                lines.append(node.lineno)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            arg = node.args[0].value
            if name in ("import_module", "__import__") and isinstance(arg, str) and arg.split(".")[0] == "rerun":
                lines.append(node.lineno)
    return lines


def _dotted(node: ast.AST) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return None


def global_random_uses(tree: ast.Module) -> list[tuple[int, str]]:
    """``np.random.X`` / ``numpy.random.X`` / ``from numpy.random import X`` with X not a generator constructor."""
    # Names bound to numpy and numpy.random in this module.
    np_names, npr_names = {"numpy"}, set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name == "numpy":
                    np_names.add(a.asname or "numpy")
                elif a.name == "numpy.random" and a.asname:
                    npr_names.add(a.asname)
        elif isinstance(node, ast.ImportFrom) and node.module == "numpy":
            npr_names.update(a.asname or a.name for a in node.names if a.name == "random")
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module == "numpy.random":
            bad += [(node.lineno, f"from numpy.random import {a.name}") for a in node.names
                    if a.name not in ALLOWED_NP_RANDOM]
        elif isinstance(node, ast.Attribute):
            d = _dotted(node)
            if d is None:
                continue
            parts = d.split(".")
            if len(parts) == 3 and parts[0] in np_names and parts[1] == "random":
                if parts[2] not in ALLOWED_NP_RANDOM:
                    bad.append((node.lineno, d))
            elif len(parts) == 2 and parts[0] in npr_names and parts[1] not in ALLOWED_NP_RANDOM:
                bad.append((node.lineno, d))
    return bad


def test_sources_found():
    names = {rel(p) for p in SOURCES}
    assert {"covviz/spd.py", "covviz/trackers/manifold.py", "covviz/cli.py"} <= names


@pytest.mark.parametrize("path", [p for p in SOURCES if not may_import_rerun(p)], ids=rel)
def test_only_viz_and_cli_import_rerun(path):
    assert rerun_imports(parse(path)) == [], f"{rel(path)} imports rerun; move that code to covviz/viz/"


@pytest.mark.parametrize("path", SOURCES, ids=rel)
def test_no_global_numpy_randomness(path):
    bad = global_random_uses(parse(path))
    assert bad == [], f"{rel(path)} uses global numpy randomness {bad}; take an rng and call np.random.default_rng(rng)"


def test_checkers_catch_what_they_should():
    """The AST checks themselves flag the patterns they are meant to flag (and not the allowed ones)."""
    src = """
import numpy as np
import numpy.random as npr
from numpy.random import default_rng, seed
import rerun as rr
from rerun.blueprint import Blueprint
np.random.seed(0)
x = np.random.rand(3)
y = npr.normal()
g = np.random.default_rng(0)
s = np.random.SeedSequence(1).spawn(2)
"""
    tree = ast.parse(src)
    assert rerun_imports(tree) == [5, 6]
    found = {d for _, d in global_random_uses(tree)}
    assert found == {"from numpy.random import seed", "np.random.seed", "np.random.rand", "npr.normal"}
    assert rerun_imports(ast.parse("import importlib\nimportlib.import_module('rerun')")) == [2]


def core_modules() -> list[str]:
    core = ["spd", "features", "descriptor", "dynamics", "particles", "records", "runner", "sequences",
            "metrics", "results"]
    mods = [f"covviz.{m}" for m in core if (PACKAGE / f"{m}.py").is_file()]
    mods += [f"covviz.trackers.{p.stem}" for p in sorted((PACKAGE / "trackers").glob("*.py")) if p.stem != "__init__"]
    return ["covviz", "covviz.trackers", *mods]


def test_core_modules_import_without_rerun():
    mods = core_modules()
    assert "covviz.trackers.manifold" in mods and "covviz.spd" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "    loaded = sorted(k for k in sys.modules if k == 'rerun' or k.startswith('rerun.'))\n"
        "    if loaded:\n"
        "        print(m, loaded[:3]); sys.exit(1)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, f"importing {p.stdout.strip()} pulled in rerun\n{p.stderr[-2000:]}"
