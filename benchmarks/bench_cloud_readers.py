"""Speed of metro's strict ASCII PLY reader against Open3D's ASCII PLY reader, same run.

    python benchmarks/bench_cloud_readers.py [--n 1e6] [--repeat 3] [--workdir DIR]

An ASCII PLY of ``--n`` vertices (``float x y z`` with 7 significant digits, as scanner
software writes them, plus a ``uchar intensity``; seeded) is written once. Then, in this
process, in turn (best of ``--repeat``):

- ``metro``: :func:`metrology.io.clouds.read_cloud` (strict header, every token checked
  against its type and range, every row's length, the element count, trailing content);
- ``o3d``: Open3D's ``read_point_cloud`` on the same file (what metro used before issue 11;
  it does none of these checks);
- ``plyfile`` (if installed): ``PlyData.read`` of the file, the strict library alternative.

Reported: seconds each, and ``metro / o3d`` and ``plyfile / metro`` ratios.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from metrology.io._o3d import open3d  # noqa: E402
from metrology.io.clouds import read_cloud  # noqa: E402


def write_ascii_ply(path, n, rng):
    P = rng.uniform(-500, 500, size=(n, 3))
    inten = rng.integers(0, 256, size=n)
    head = ("ply\nformat ascii 1.0\ncomment bench_cloud_readers\n"
            f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            "property uchar intensity\nend_header\n")
    with open(path, "w") as fh:
        fh.write(head)
        np.savetxt(fh, np.column_stack([P, inten]), fmt=["%.7g", "%.7g", "%.7g", "%d"])
    return P


def best(fn, repeat):
    out, times = None, []
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return min(times), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=float, default=1e6)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--workdir", default=None)
    args = ap.parse_args(argv)
    n = int(args.n)
    o3d = open3d()
    with tempfile.TemporaryDirectory(dir=args.workdir) as tmp:
        path = Path(tmp) / "cloud.ply"
        write_ascii_ply(path, n, np.random.default_rng(11))
        print(f"ASCII PLY, {n} vertices, {path.stat().st_size / 1e6:.1f} MB")

        def metro():
            return read_cloud(path)

        def o3d_read():
            return np.asarray(o3d.io.read_point_cloud(str(path)).points)

        try:
            import plyfile
        except ImportError:
            plyfile = None
        results = {}
        for _ in range(args.repeat):  # candidates in turn, so machine load hits them alike
            for name, fn in [("metro", metro), ("o3d", o3d_read)] + ([("plyfile", lambda: plyfile.PlyData.read(str(path)))] if plyfile else []):
                t, out = best(fn, 1)
                results[name] = min(results.get(name, (np.inf, None))[0], t), out
        a, b = results["metro"][1], results["o3d"][1]
        same = np.array_equal(a.astype(np.float32), b.astype(np.float32))
        for name, (t, _) in results.items():
            print(f"{name:8s} {t:7.3f} s")
        print(f"metro / o3d = {results['metro'][0] / results['o3d'][0]:.2f}  (same points at float32: {same})")
        if "plyfile" in results:
            print(f"plyfile / metro = {results['plyfile'][0] / results['metro'][0]:.2f}")


if __name__ == "__main__":
    main()
