#!/bin/bash
# Golden outputs of `metro measure` (issue 49): every output of one process, Dask, --follow, --panel,
# --points, --qif on forward-simulated logs, to compare byte for byte before and after a refactor.
#
#   benchmarks/golden_measure.sh WORKDIR OUTDIR     # makes the logs in WORKDIR once, the outputs in OUTDIR
#   diff -r OUT_BEFORE OUT_AFTER
#   python benchmarks/golden_diff.py OUT_BEFORE OUT_AFTER   # how far they differ, per table and column
#
# Expected changes (everything else byte-identical but for the tree's path in the warnings):
# - issue 49, one estimator (metrology/measure/estimator.py, benchmarks/results/measure_weights_issue49.md):
#   4-sensor holes weighted by 1/(sigma u_z)^2; calflat's U95 by <= 9e-4 deg, --panel/--points angles by
#   <= 1e-3 deg and their fit_residual_um's sign flipped (one sign, the micro-plane's); equal weights (flat,
#   part1, dask) and 3 sensors by rounding (<= 2e-14 deg); no status changes.
# - issue 51 item 5, rules 2b and 3b (benchmarks/results/gross_issue51_item5.md): without --panel/--points, the U95
#   of a 4-sensor pose whose misfit is beyond 6 sigmas within the R 500 bound (flat: 35 before, 80 after, the
#   nominal layout's head 15-30 um off it; follow alike); no status changes there; --panel/--points byte-identical.
# - issue 49 item 3, the unstated convention's alias (metrology/measure/spin.py SPIN_ALIAS_SHARE, docs/spin.md):
#   wing_nopose only (4 sensors, no pose, no --spin-deg): 1641 of 2000 holes' before-readings judged over every spin
#   (angle_deg, U95_angle_deg: median 0.0079 -> 0.0224 deg; their reason), the rest's reason "" for null, the after's
#   angle by <= 2e-6 deg (the spin it keeps from before), the summary's means by <= 2e-7 deg; no status changes.
# - issue 49 item 4 (b), the results' Parquet encoding (metrology/io/holeout.py parquet_options,
#   benchmarks/results/measure_speed_issue49_r6.md): part1/ and dask/ hold other bytes, the same tables
#   (pyarrow.parquet.read_table(...).equals: python benchmarks/golden_diff.py OUT_BEFORE OUT_AFTER); the rest byte-identical.
# - the summary's counts of rule 2b's and the alias rule's holes (metrology/measure/summary.py, docs/gross.md, docs/spin.md):
#   *.stdout only (--json): without --panel/--points curvature.one_sensor_offset_holes (flat 80, part1 and dask 3, calflat
#   and flat3 0) and, on 4 sensors, a check line of it in verdict.checks; with them curvature.spin_alias_holes (wing_nopose
#   1641, the others 0) and, on 4 sensors with the convention not stated (wing_nopose), a check line of it; every other
#   file byte-identical.
# - issue 49 item 4 (a), a small hole table's closest points by trimesh's double-precision engine (metrology/panel/holes.py
#   DOUBLE_ENGINE_WORK, benchmarks/results/measure_panel_speed_issue49_r6.md): --panel/--points outputs by rounding, the
#   closest triangle the true one where Open3D's float32 picked a neighbour (wing, wing3, wing_nopose, wing3_nopose,
#   follow_wing: angle_deg <= 2e-9 deg, normal_vs_cad_deg <= 5e-7 deg; barrel <= 1e-14 deg; wing.qif a last digit);
#   no status changes.
# - issue 49 item 4 (b), r7: the budget's arithmetic reordered (benchmarks/results/measure_speed_issue49_r7.md): the
#   U95 columns only, at rounding level: flat/part1/dask/calflat/flat3/flat3inf U95_angle_deg and U95_after_deg by
#   <= 1.8e-15 deg (flat3's after; the others <= 6e-16), the --json summaries' U95_deg and follow's per-hole U95 by
#   <= 9e-16 deg; angles, normals, misfits, statuses, reasons, counts and every --panel/--points output byte-identical.
set -e
WD=$(realpath -m "$1"); O=$(realpath -m "$2"); mkdir -p "$WD" "$O"
W=$(cd "$(dirname "$0")/.." && pwd)/metrology/data; L=$W/measured/nominal.toml; P=$W/panels
cd "$WD"
if [ ! -f done ]; then
  metro calibrate $W/measured/calibration.csv --plane $W/measured/plane.json --layout $L --out cal.toml 2>/dev/null
  python - <<'PY'
import pyarrow.csv as c
import metrology.io.layout as m
m.save_layout(m.load_layout('cal.toml').subset(['L1', 'L2', 'L3']), 'cal3.toml')
PY
  python -c "import metrology.io.layout as m, sys; m.save_layout(m.load_layout(sys.argv[1]).subset(['L1','L2','L3']), 'nom3.toml')" $L
  metro simulate-log --out flat.csv --holes 3000 --seed 3 --gross-rate 0.002 >/dev/null
  metro simulate-log --out wing.csv --holes 2000 --seed 5 --panel $P/wing.stl --points $P/wing.holes.csv --true-layout $L --spin-deg 1 >/dev/null
  metro simulate-log --out barrel.csv --holes 1500 --seed 6 --panel $P/barrel.stl --points $P/barrel.holes.csv --true-layout $L >/dev/null
  metro simulate-log --out part --holes 4000 --cells 2 --seed 7 >/dev/null
  metro simulate-log --out calflat.parquet --layout cal.toml --holes 3000 --seed 8 >/dev/null
  metro simulate-log --out flat3.csv --layout cal3.toml --holes 2000 --seed 9 >/dev/null
  metro simulate-log --out wing3.csv --layout nom3.toml --true-layout nom3.toml --holes 1500 --seed 10 --panel $P/wing.stl --points $P/wing.holes.csv >/dev/null
  metro simulate-log --out nacelle.csv --holes 1500 --seed 12 --panel $P/nacelle.stl --points $P/nacelle.holes.csv --true-layout $L --layout $L >/dev/null
  python - <<'PY'
import pyarrow.csv as c
for f in ('wing', 'wing3'):
    t = c.read_csv(f + '.csv')
    c.write_csv(t.drop([n for n in t.column_names if n.startswith('pose_')]), f + '_nopose.csv')
PY
  touch done
fi
m() { name=$1; shift; metro measure "$@" > $O/$name.stdout 2> $O/$name.stderr || true; }
m flat flat.csv --layout $L --out $O/flat.csv --json
m calflat calflat.parquet --layout cal.toml --out $O/calflat.csv --json --qif $O/calflat.qif
m flat3 flat3.csv --layout cal3.toml --out $O/flat3.csv --json
m flat3inf flat3.csv --layout cal3.toml --out $O/flat3inf.csv --min-radius-mm inf
m wing wing.csv --layout $L --panel $P/wing.stl --points $P/wing.holes.csv --out $O/wing.csv --qif $O/wing.qif --json
m barrel barrel.csv --layout $L --panel $P/barrel.stl --points $P/barrel.holes.csv --out $O/barrel.csv --json
m nacelle_pts nacelle.csv --layout $L --points $P/nacelle.holes.csv --out $O/nacelle_pts.csv --json
m wing3 wing3.csv --layout nom3.toml --panel $P/wing.stl --points $P/wing.holes.csv --out $O/wing3.csv --json
m part1 part --layout $L --out $O/part1 --json
m dask part --layout $L --out $O/dask --json --workers 1
m follow flat.csv --layout $L --follow
m follow_wing wing.csv --layout $L --follow --panel $P/wing.stl --points $P/wing.holes.csv
m wing_nopose wing_nopose.csv --layout $L --panel $P/wing.stl --points $P/wing.holes.csv --out $O/wing_nopose.csv --json
m wing3_nopose wing3_nopose.csv --layout nom3.toml --panel $P/wing.stl --points $P/wing.holes.csv --out $O/wing3_nopose.csv --json
