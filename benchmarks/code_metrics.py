"""Code metrics of the diagnosis engine (``metrology/diagnosis``, ``metrology/core/effects``, ``calibration/engine``).

    PYTHONPATH=<tree> python benchmarks/code_metrics.py [--root <tree>] [--no-trace]

Static (``ast``): the module count, the largest functions (lines, ``def`` to its last line),
the functions taking more than 6 parameters (``self``/``cls`` not counted, ``*args``/``**kw``
counted once each). Dynamic (``--no-trace`` skips it): the modules a reader opens to follow
one verdict from data to words, measured by running ``diagnose`` on the bundled ``hidden``
data set under ``sys.setprofile`` and listing, in the order they are first called, the
functions of the two packages (each read once, where it is first met, as a reader following
the calls would). Reported: the modules in the order first opened, and how many times the
reading moves to another module (``switches``) and comes back to one it had left (``returns``).
"""

from __future__ import annotations

import argparse
import ast
import sys
from pathlib import Path

#: the engine: the diagnosis, the effect registry, and the least-squares engine the diagnosis fits with
#: (in ``diagnosis/fit.py`` before issue 30; a path missing from a tree is skipped)
PACKAGES = ("metrology/diagnosis", "metrology/core/effects", "metrology/calibration/engine.py")
MAX_PARAMS = 6


def functions(path: Path):
    """``(qualified name, lines, parameters)`` of every function of a module."""
    tree = ast.parse(path.read_text())
    out = []

    def visit(node, prefix):
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = ch.args
                names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
                if names and names[0] in ("self", "cls"):
                    names = names[1:]
                n = len(names) + (a.vararg is not None) + (a.kwarg is not None)
                out.append((prefix + ch.name, ch.end_lineno - ch.lineno + 1, n))
                visit(ch, prefix + ch.name + ".")
            elif isinstance(ch, ast.ClassDef):
                visit(ch, prefix + ch.name + ".")
            else:
                visit(ch, prefix)

    visit(tree, "")
    return out


def static(root: Path) -> dict:
    mods = sorted(p for pkg in PACKAGES for p in ([root / pkg] if pkg.endswith(".py") else (root / pkg).glob("*.py"))
                  if p.exists())
    rows = []
    for m in mods:
        rel = m.relative_to(root).as_posix()
        rows += [(rel, *f) for f in functions(m)]
    rows.sort(key=lambda r: -r[2])
    return {"modules": len(mods), "modules_list": [m.relative_to(root).as_posix() for m in mods],
            "lines": sum(len(m.read_text().splitlines()) for m in mods),
            "functions": len(rows), "largest": rows[:5],
            "over_params": sorted([r for r in rows if r[3] > MAX_PARAMS], key=lambda r: -r[3])}


def reading_order(root: Path) -> dict:
    """Run ``diagnose`` on the bundled hidden data set and list the modules in reading order."""
    sys.path.insert(0, str(root))
    import metrology
    from metrology.jobs.diagnose import diagnose_files

    pkg_dirs = [str((root / p).resolve()) + ("" if p.endswith(".py") else "/") for p in PACKAGES]
    first_seen, order = set(), []

    def prof(frame, event, arg):
        if event != "call":
            return
        code = frame.f_code
        if code in first_seen:
            return
        first_seen.add(code)
        fn = code.co_filename
        if any(fn.startswith(d) for d in pkg_dirs) and code.co_name not in ("<listcomp>", "<genexpr>", "<dictcomp>",
                                                                            "<setcomp>", "<lambda>"):
            order.append((Path(fn).resolve().relative_to(root.resolve()).as_posix(), code.co_qualname))

    data = Path(metrology.__file__).parent / "data" / "hidden"
    sys.setprofile(prof)
    try:
        diagnose_files(str(data / "export.csv"), str(data / "plane.json"), str(data / "layout.toml"))
    finally:
        sys.setprofile(None)
    seq = []
    for mod, _ in order:
        if not seq or seq[-1] != mod:
            seq.append(mod)
    opened, returns = [], 0
    for mod in seq:
        if mod in opened:
            returns += 1
        else:
            opened.append(mod)
    return {"functions_read": len(order), "modules_opened": opened, "switches": len(seq) - 1, "returns": returns}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--root", default=str(Path(__file__).resolve().parents[1]))
    ap.add_argument("--no-trace", action="store_true")
    a = ap.parse_args(argv)
    root = Path(a.root)
    s = static(root)
    print(f"modules: {s['modules']} ({s['lines']} lines, {s['functions']} functions)")
    print("largest functions:")
    for mod, name, n, k in s["largest"]:
        print(f"  {n:4d} lines  {mod}:{name} ({k} parameters)")
    print(f"functions with more than {MAX_PARAMS} parameters: {len(s['over_params'])}")
    for mod, name, n, k in s["over_params"]:
        print(f"  {k:3d} parameters  {mod}:{name}")
    if not a.no_trace:
        r = reading_order(root)
        print(f"one verdict from data to words (bundled 'hidden' data set): {r['functions_read']} functions read in "
              f"{len(r['modules_opened'])} modules, {r['switches']} moves between modules, {r['returns']} returns "
              "to a module left before")
        print("  modules in the order first opened: " + ", ".join(m.split("/", 1)[1] for m in r["modules_opened"]))


if __name__ == "__main__":
    main()
