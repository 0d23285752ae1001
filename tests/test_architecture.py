"""The folder tree is the architecture: imports point one way, no cycles, small modules.

Read from the source with ``ast`` (in-function imports included), so a cycle hidden in a
lazy import is found as well as a top-level one. The layers, lowest first, are drawn in
``docs/architecture.md``.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "metrology"

#: Layer of each subpackage: a module may import its own subpackage and lower layers only.
LAYERS = {
    "core": 0,
    "io": 1,
    "datum": 2, "calibration": 2, "panel": 2, "measure": 2, "plant": 2,
    "diagnosis": 3, "sim": 3, "plan": 3,
    "report": 4, "jobs": 5,
}
#: Same-layer imports that are allowed (the arrow is drawn in docs/architecture.md).
SIDEWAYS = {("calibration", "datum")}  # a dataset's --plane may be a cloud: the datum fit
MAX_LINES = 500


def _module_name(path: Path) -> str:
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _imports(path: Path) -> set[str]:
    """Every ``metrology.*`` module that ``path`` imports, anywhere in the file."""
    tree = ast.parse(path.read_text(), filename=str(path))
    me = _module_name(path).split(".")
    package = me if path.name == "__init__.py" else me[:-1]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("metrology")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            if base.startswith("metrology"):
                out.add(base)
                # "from metrology.x import y": y may itself be a module
                out |= {f"{base}.{a.name}" for a in node.names
                        if (PKG.parent / (f"{base}.{a.name}".replace(".", "/") + ".py")).exists()
                        or (PKG.parent / f"{base}.{a.name}".replace(".", "/")).is_dir()}
    return out


def _graph():
    mods = {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}
    return mods, {m: {i for i in _imports(p) if i in mods and i != m} for m, p in mods.items()}


def _subpackage(mod: str) -> str | None:
    parts = mod.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in LAYERS) else None


def test_every_subpackage_has_a_layer():
    subs = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert subs <= set(LAYERS), f"subpackages without a layer: {sorted(subs - set(LAYERS))}"


def test_imports_point_down_the_layers():
    _, graph = _graph()
    wrong = []
    for mod, deps in graph.items():
        a = _subpackage(mod)
        for dep in deps:
            b = _subpackage(dep)
            if a is None or b is None or a == b:
                continue
            if LAYERS[b] > LAYERS[a] or (LAYERS[b] == LAYERS[a] and (a, b) not in SIDEWAYS):
                wrong.append(f"{mod} -> {dep}")
    assert not wrong, "imports against the layers:\n" + "\n".join(sorted(wrong))


def test_no_import_cycle():
    import networkx as nx

    _, graph = _graph()
    g = nx.DiGraph([(m, d) for m, deps in graph.items() for d in deps
                    if not (m == "metrology" or d == "metrology")])
    # a package's __init__ re-exporting its own modules is not a cycle of concepts
    g.remove_edges_from([(m, d) for m, d in list(g.edges) if d.startswith(m + ".") or m.startswith(d + ".") and
                         (PKG.parent / d.replace(".", "/") / "__init__.py").exists()])
    cycles = list(nx.simple_cycles(g))
    assert not cycles, f"import cycles: {cycles[:5]}"


def test_the_cycle_check_finds_a_cycle(tmp_path):
    """The check itself can fail: two modules importing each other inside functions."""
    import networkx as nx

    a, b = tmp_path / "a.py", tmp_path / "b.py"
    a.write_text("def f():\n    from metrology.x import b\n")
    b.write_text("def g():\n    import metrology.x.a\n")
    found = {}
    for p in (a, b):
        tree = ast.parse(p.read_text())
        found[p.stem] = {n.module + "." + n.names[0].name if isinstance(n, ast.ImportFrom) else n.names[0].name
                         for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))}
    g = nx.DiGraph([("metrology.x." + k, d) for k, deps in found.items() for d in deps])
    assert list(nx.simple_cycles(g))


def test_no_module_over_the_size_limit():
    big = {str(p.relative_to(ROOT)): n for p in PKG.rglob("*.py") if (n := len(p.read_text().splitlines())) > MAX_LINES}
    assert not big, f"modules over {MAX_LINES} lines: {big}"


@pytest.mark.parametrize("entry", ["cli.main", "metrology"])
def test_heavy_libraries_load_lazily(entry):
    """``metro --help`` stays fast: importing the CLI or the package pulls in no heavy library."""
    code = (f"import sys, {entry}; heavy = [m for m in ('numpy', 'scipy', 'open3d', 'trimesh', 'matplotlib', "
            f"'filterpy', 'pyarrow') if m in sys.modules]; print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout
    allowed = {"numpy"} if entry == "metrology" else set()
    assert set(filter(None, out.strip().split(","))) <= allowed


def _doc_rows() -> dict:
    """``{subpackage: (modules, folders)}`` from the module table of docs/architecture.md: a
    backticked ``name`` is a module, ``name/ (`a`, `b`)`` the modules of a nested folder, and
    ``name/`` alone a folder standing for all of its modules."""
    import re

    rows = {}
    for line in (ROOT / "docs" / "architecture.md").read_text().splitlines():
        m = re.match(r"\| `([a-z_]+)/` \| (.*?) \| ", line)
        if not m:
            continue
        mods, folders = set(), set()
        for name, inner in re.findall(r"`([\w*]+/?)`(?:\s*\(([^)]*)\))?", m.group(2)):
            if name.endswith("/") and inner:
                mods |= {name + x for x in re.findall(r"`(\w+)`", inner)}
            elif name.endswith("/"):
                folders.add(name[:-1])
            else:
                mods.add(name)
        rows[m.group(1)] = (mods, folders)
    return rows


def test_the_module_table_is_the_tree():
    """docs/architecture.md's module table lists every module of every subpackage, and no other."""
    rows = _doc_rows()
    # a subpackage: a folder of modules (a namespace package without __init__ too)
    subs = sorted(p.name for p in PKG.iterdir() if p.is_dir() and p.name != "__pycache__" and any(p.rglob("*.py")))
    errors = []
    for sub in subs:
        tree = {str(p.relative_to(PKG / sub).with_suffix("")) for p in (PKG / sub).rglob("*.py")
                if p.name != "__init__.py"}
        if sub not in rows:
            errors.append(f"no row for metrology/{sub}/ (its modules: {', '.join(sorted(tree))})")
            continue
        mods, folders = rows[sub]
        covered = {m for m in tree if m.split("/")[0] in folders and "/" in m}
        missing = sorted(tree - mods - covered)
        extra = sorted(mods - tree) + sorted(f + "/" for f in folders if not (PKG / sub / f).is_dir())
        if missing:
            errors.append(f"row `{sub}/` does not list: {', '.join(missing)}")
        if extra:
            errors.append(f"row `{sub}/` lists what is not in the tree: {', '.join(extra)}")
    errors += [f"row `{r}/` has no subpackage metrology/{r}/" for r in sorted(set(rows) - set(subs) - {"cli"})]
    assert not errors, "docs/architecture.md, module table:\n" + "\n".join(errors)
