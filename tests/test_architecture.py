"""Architecture rules of covviz, checked on the source (STYLE.md: data flow, randomness passed in).

* Only ``covviz/viz/`` and ``covviz/cli/`` import ``rerun``: the tracker core
  knows nothing of the instrumentation.
* No global numpy randomness anywhere in the package (``np.random.seed``,
  ``np.random.rand`` …): every stochastic function takes an ``rng``.
* The core modules import without pulling ``rerun`` into ``sys.modules``
  (checked in a fresh interpreter).
* No import cycles between the package's modules, counting imports inside
  functions (a lazy import hides a cycle from the interpreter, not from a
  reader).
* ``covviz/viz`` calls no private member of a tracker.
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
    return r.startswith(("covviz/viz/", "covviz/cli/"))


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
    assert {"covviz/model/spd.py", "covviz/trackers/manifold.py", "covviz/cli/track.py"} <= names


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


#: Modules of covviz/viz that compute or drive the viewer without logging: they stay free of rerun.
RERUN_FREE_VIZ = ("covviz.viz", "covviz.viz.defaults", "covviz.viz.paths", "covviz.viz.mds_figures",
                  "covviz.viz.why_manifold", "covviz.viz.snapshot")


def core_modules() -> list[str]:
    mods = []
    for p in SOURCES:
        name = module_name(p)
        if not may_import_rerun(p) or name in RERUN_FREE_VIZ:
            mods.append(name)
    return sorted(set(mods) | {"covviz.cli"} | set(RERUN_FREE_VIZ))


def test_core_modules_import_without_rerun():
    mods = core_modules()
    assert "covviz.trackers.manifold" in mods and "covviz.model.spd" in mods and "covviz.cli" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "    loaded = sorted(k for k in sys.modules if k == 'rerun' or k.startswith('rerun.'))\n"
        "    if loaded:\n"
        "        print(m, loaded[:3]); sys.exit(1)\n"
        "import covviz.cli\n"
        "covviz.cli.build_parser()  # every --help is built without the viewer's library\n"
        "assert not any(k == 'rerun' or k.startswith('rerun.') for k in sys.modules)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, f"importing {p.stdout.strip()} pulled in rerun\n{p.stderr[-2000:]}"


#: The optional extra ``cluster``: imported lazily, only by --cluster and covviz tune.
EXTRA_MODULES = ("dask", "distributed", "optuna")


def test_the_core_and_the_cli_load_no_cluster_extra():
    """Importing every module (covviz.experiments.cluster and covviz.experiments.tune included) and building the CLI loads
    neither Dask nor Optuna: the core install stays as light as without the extra."""
    mods = core_modules()
    assert "covviz.experiments.cluster" in mods and "covviz.experiments.tune" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "import covviz.cli\n"
        "covviz.cli.build_parser()\n"
        f"bad = sorted(k for k in sys.modules if k.split('.')[0] in {EXTRA_MODULES!r})\n"
        "print(bad[:5]); sys.exit(1 if bad else 0)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, f"the core imported {p.stdout.strip()}\n{p.stderr[-2000:]}"


def test_numba_loads_only_with_the_kernels():
    """numba (and its ~1 s of import) is pulled in by covviz.model.kernels alone, at the first compiled call:
    every other module, and the CLI's --help, load without it."""
    mods = [m for m in core_modules() if m != "covviz.model.kernels"]
    assert "covviz.model.observation" in mods and "covviz.trackers.manifold" in mods
    code = (
        "import importlib, sys\n"
        f"for m in {mods!r}:\n"
        "    importlib.import_module(m)\n"
        "    if 'numba' in sys.modules:\n"
        "        print(m); sys.exit(1)\n"
        "import covviz.cli\n"
        "covviz.cli.build_parser()\n"
        "sys.exit(1 if 'numba' in sys.modules else 0)\n"
    )
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert p.returncode == 0, f"importing {p.stdout.strip() or 'the CLI'} loaded numba\n{p.stderr[-2000:]}"


# --------------------------------------------------------------------------- #
# import cycles
# --------------------------------------------------------------------------- #
def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {module_name(p): p for p in SOURCES}


def imported_modules(name: str, tree: ast.Module, modules=None) -> set[str]:
    """The package modules ``name`` imports anywhere in its source (functions included).

    ``from a.b import c`` counts as importing ``a.b.c`` when that is a module,
    else ``a.b``; ``importlib.import_module("a.b")`` with a literal counts too.
    A module's own ancestor packages are left out (importing a submodule always
    runs its package's ``__init__``; that is not a cycle of ours).
    """
    modules = MODULES if modules is None else modules
    is_pkg = name in modules and modules[name].name == "__init__.py"
    package = name if is_pkg else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            subs = [f"{mod}.{a.name}" for a in node.names if f"{mod}.{a.name}" in modules]
            found.update(subs)
            if len(subs) < len(node.names):
                found.add(mod)
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant):
            f = node.func
            fname = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if fname == "import_module" and isinstance(node.args[0].value, str):
                found.add(node.args[0].value)
    out = set()
    ancestors = {".".join(name.split(".")[:k]) for k in range(1, name.count(".") + 1)}
    for m in found:
        while m and m not in modules:
            m = m.rpartition(".")[0]
        if m and m != name and m not in ancestors:
            out.add(m)
    return out


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycles():
    graph = {name: imported_modules(name, parse(p)) for name, p in MODULES.items()}
    assert "covviz.experiments.bench" in graph["covviz.cli.bench"]  # the graph sees lazy imports inside functions
    cycles = import_cycles(graph)
    detail = "; ".join(
        " <-> ".join(c) + " (" + ", ".join(f"{a} -> {sorted(graph[a] & set(c))}" for a in c) + ")" for c in cycles
    )
    assert cycles == [], f"import cycles in covviz: {detail}"


def test_cycle_checker_sees_lazy_imports_and_relative_ones():
    mods = {"p": Path("p/__init__.py"), "p.a": Path("p/a.py"), "p.b": Path("p/b.py"), "p.c": Path("p/c.py")}
    a = ast.parse("def f():\n    from p.b import thing\n")
    b = ast.parse("from . import c\nimport importlib\nimportlib.import_module('p.a')\n")
    c = ast.parse("from p import a\n")
    graph = {
        "p.a": imported_modules("p.a", a, mods),
        "p.b": imported_modules("p.b", b, mods),
        "p.c": imported_modules("p.c", c, mods),
    }
    assert graph == {"p.a": {"p.b"}, "p.b": {"p.c", "p.a"}, "p.c": {"p.a"}}
    assert import_cycles(graph) == [["p.a", "p.b", "p.c"]]
    assert import_cycles({"x": {"y"}, "y": set()}) == []


# --------------------------------------------------------------------------- #
# the recorder asks the frozen model, never the tracker's private parts
# --------------------------------------------------------------------------- #
def private_tracker_uses(tree: ast.Module) -> list[tuple[int, str]]:
    """``<something>.tracker._x`` / ``tracker._x`` / ``tr._x`` attribute reads (private members of a tracker)."""
    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__"):
            owner = _dotted(node.value) or ""
            last = owner.rpartition(".")[2]
            if last in ("tracker", "tr", "trk") or last.endswith("_tracker"):
                bad.append((node.lineno, f"{owner}.{node.attr}"))
    return sorted(bad)


@pytest.mark.parametrize("path", [p for p in SOURCES if rel(p).startswith("covviz/viz/")], ids=rel)
def test_viz_calls_no_private_member_of_a_tracker(path):
    assert private_tracker_uses(parse(path)) == [], f"{rel(path)} reaches into a tracker's private state"


def test_private_member_checker():
    tree = ast.parse("s.tracker._observe(x)\ntr._step\nself._state\ntracker.observe()\n")
    assert private_tracker_uses(tree) == [(1, "s.tracker._observe"), (2, "tr._step")]
