"""Issue 49's speed goals in one run, rounds interleaved (CPU seconds, user + system, of each process):

    python benchmarks/measure_rounds.py WORKDIR ROUNDS OUT.json [--wing-csv WING.csv] [--no-panel-1e6]

WORKDIR holds ``log_before.parquet`` and ``calibrated.toml`` (``bench_measure.py --sections verdicts --workdir``
makes them: 1e6 holes, no after-readings). ``wing50.parquet`` and ``wing500.parquet`` are the golden wing log
(``golden_measure.sh``'s ``wing.csv``, 2000 posed holes with after-readings) tiled 50 and 500 times (1e5 and 1e6
holes, hole ids made unique, times shifted); ``--wing-csv`` makes them where they are missing, and ``tiny.parquet``
(the first 1000 rows of ``log_before.parquet``) is made here.

Each round runs: the plain script (``bench_measure.BASELINE``), ``metro measure`` with every hole failing
(``--tolerance-deg 0.1``) and every hole conforming (``10``), the output contract's floor (``measure_io_floor.FLOOR``:
the columns metro reads), the floor reading every column (``floor_every_column``), ``metro measure`` of the wing logs
with ``--panel --points`` and without (1e5 holes, and 1e6 as ``bench_measure.py --sections panel`` counts them);
and the fixed costs: ``metro measure`` refused at its first check (a log that does not exist: the interpreter,
the CLI's parse and metro's modules, nothing read), and ``metro measure`` and the plain script on ``tiny.parquet``
(1000 holes: every import and setup of a whole run). The ratios of one round are the figure on a shared machine;
the load average before and after each round is kept.
"""
import argparse, os, subprocess, sys, json, time
from pathlib import Path
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_measure import BASELINE, RUN, _ENV  # noqa: E402
from measure_io_floor import FLOOR, READ  # noqa: E402


def tile(csv, times, out):
    """The log ``csv`` repeated ``times`` times into ``out`` (Parquet): hole ids suffixed, times shifted."""
    import pyarrow as pa, pyarrow.csv as pcsv, pyarrow.compute as pc, pyarrow.parquet as pq
    t = pcsv.read_csv(csv)
    span = pc.max(t['time']).as_py() - pc.min(t['time']).as_py() + 10
    parts = [t.set_column(0, 'hole_id', pc.binary_join_element_wise(t['hole_id'], pa.scalar(f'_{k:03d}'), ''))
              .set_column(1, 'time', pc.add(t['time'], k * span)) for k in range(times)]
    pq.write_table(pa.concat_tables(parts), out)


ap = argparse.ArgumentParser()
ap.add_argument('workdir'); ap.add_argument('rounds', type=int); ap.add_argument('out')
ap.add_argument('--wing-csv', help="golden_measure.sh's wing.csv, to make the tiled wing logs where missing")
ap.add_argument('--no-panel-1e6', action='store_true', help='leave out the 1e6-hole panel pair (about 20 s a round)')
a = ap.parse_args()
W = a.workdir; LOG = f'{W}/log_before.parquet'; LAY = f'{W}/calibrated.toml'
for k, name in ((50, 'wing50'), (500, 'wing500')):
    if not os.path.exists(f'{W}/{name}.parquet'):
        tile(a.wing_csv, k, f'{W}/{name}.parquet')
if not os.path.exists(f'{W}/tiny.parquet'):
    import pyarrow.parquet as pq
    pq.write_table(pq.ParquetFile(LOG).read_row_group(0).slice(0, 1000), f'{W}/tiny.parquet')
D = str(HERE.parent / 'metrology' / 'data')
metro = [os.path.join(os.path.dirname(sys.executable), 'metro')]
EVERY = FLOOR.replace(READ, "columns=None")  # every column read (the contract before metro left its unused inputs unread)
PANEL = ['--panel', f'{D}/panels/wing.stl', '--points', f'{D}/panels/wing.holes.csv']


def wing(n):
    return [*metro, '-q', 'measure', f'{W}/{n}.parquet', '--layout', f'{D}/measured/nominal.toml', '--out', f'{W}/o_{n}.parquet']


cmds = {'baseline': [sys.executable, '-c', BASELINE, LOG, LAY, f'{W}/o_base.parquet'],
        'fail': [*metro, '-q', 'measure', LOG, '--layout', LAY, '--out', f'{W}/o_fail.parquet', '--tolerance-deg', '0.1'],
        'conform': [*metro, '-q', 'measure', LOG, '--layout', LAY, '--out', f'{W}/o_conf.parquet', '--tolerance-deg', '10'],
        'floor': [sys.executable, '-c', FLOOR, LOG, LAY, f'{W}/o_floor.parquet'],
        'floor_every_column': [sys.executable, '-c', EVERY, LOG, LAY, f'{W}/o_floor2.parquet'],
        'nopanel': wing('wing50'),
        'panel': [*wing('wing50'), *PANEL],
        'metro_refused': [*metro, '-q', 'measure', f'{W}/no_such_log.parquet', '--layout', LAY, '--out', f'{W}/o_x.parquet'],
        'metro_tiny': [*metro, '-q', 'measure', f'{W}/tiny.parquet', '--layout', LAY, '--out', f'{W}/o_tiny.parquet',
                       '--tolerance-deg', '0.1'],
        'baseline_tiny': [sys.executable, '-c', BASELINE, f'{W}/tiny.parquet', LAY, f'{W}/o_base_tiny.parquet'],
        'python': [sys.executable, '-c', 'pass']}
if not a.no_panel_1e6:
    cmds.update(nopanel_1e6=wing('wing500'), panel_1e6=[*wing('wing500'), *PANEL])


def cpu(name, c):
    r = subprocess.run([sys.executable, '-c', RUN, *c], capture_output=True, text=True, check=True, env=_ENV)
    dt, kb, rc, t = r.stdout.split()
    assert int(rc) in ((2,) if name == 'metro_refused' else (0, 1)), (c, rc)
    return float(t)


for n, c in cmds.items():
    cpu(n, c)
res = []
for k in range(a.rounds):
    l0 = os.getloadavg()[0]
    t = {n: cpu(n, c) for n, c in cmds.items()}
    t['load'] = (l0, os.getloadavg()[0]); t['utc'] = time.strftime('%H:%M:%S', time.gmtime())
    for n in ('fail', 'conform', 'floor', 'floor_every_column'):
        t[f'{n}/baseline'] = t[n] / t['baseline']
    t['panel/nopanel'] = t['panel'] / t['nopanel']
    if 'panel_1e6' in t:
        t['panel_1e6/nopanel_1e6'] = t['panel_1e6'] / t['nopanel_1e6']
    t['metro_tiny-baseline_tiny'] = t['metro_tiny'] - t['baseline_tiny']
    res.append(t)
    print(json.dumps(t), flush=True)
    json.dump(res, open(a.out, 'w'), indent=1)
