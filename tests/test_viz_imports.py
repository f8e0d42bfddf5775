"""The core never imports rerun: only covviz/viz and covviz/cli.py may."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import covviz

PACKAGE = Path(covviz.__file__).parent
IMPORT_RERUN = re.compile(r"^\s*(import\s+rerun|from\s+rerun[\s.])", re.MULTILINE)
#: Modules of covviz/viz that must stay free of rerun (pure computations).
PURE_VIZ = ("diagnostics.py",)


def test_only_viz_and_cli_import_rerun():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).as_posix()
        if rel == "cli.py" or (rel.startswith("viz/") and rel.split("/")[-1] not in PURE_VIZ):
            continue
        if IMPORT_RERUN.search(path.read_text(encoding="utf-8")):
            offenders.append(rel)
    assert offenders == [], f"rerun imported outside covviz/viz and covviz/cli.py: {offenders}"


def test_the_core_runs_without_loading_rerun():
    code = (
        "import sys\n"
        "import covviz.cli, covviz.runner, covviz.embedding, covviz.viz, covviz.viz.diagnostics\n"
        "import covviz.viz.mds_figures, covviz.viz.snapshot, covviz.viz.paths, covviz.trackers.manifold\n"
        "covviz.cli.build_parser()\n"
        "assert 'rerun' not in sys.modules, sorted(m for m in sys.modules if m.startswith('rerun'))\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=120
    )
    assert res.returncode == 0, res.stderr


def test_text_shown_in_the_viewer_has_glyphs_in_its_font():
    """A glyph missing from the viewer's font crashes the viewer (rerun 0.41): keep to the safe set."""
    from covviz.viz.description import DESCRIPTION, MDS_DESCRIPTION, viewer_safe

    for text in (DESCRIPTION, MDS_DESCRIPTION):
        assert viewer_safe(text) == text
    assert viewer_safe("Car ∇ 4 ≥ ∝") == "Car ? 4 ≥ ?"
