"""Issue 49's speed goals in one run, rounds interleaved (CPU seconds, user + system, of each process):

    python benchmarks/measure_rounds.py WORKDIR ROUNDS OUT.json

WORKDIR holds ``log_before.parquet`` and ``calibrated.toml`` (``bench_measure.py --sections verdicts --workdir``
makes them: 1e6 holes, no after-readings) and ``wing50.parquet`` (the golden wing log, ``golden_measure.sh``,
tiled 50 times: 1e5 posed holes). Each round runs: the plain script (``bench_measure.BASELINE``), ``metro
measure`` with every hole failing (``--tolerance-deg 0.1``) and every hole conforming (``10``), the output
contract's floor (``measure_io_floor.FLOOR``: the columns metro reads), the floor reading every column
(``floor_every_column``), and ``metro measure`` of the wing log with ``--panel --points`` and without. The ratios of
one round are the figure on a shared machine; the load average before and after each round is kept.
"""
import os, subprocess, sys, json, time
from pathlib import Path
HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from bench_measure import BASELINE, RUN, _ENV  # noqa: E402
from measure_io_floor import FLOOR  # noqa: E402
W = sys.argv[1]; LOG = f'{W}/log_before.parquet'; LAY = f'{W}/calibrated.toml'
D = str(HERE.parent / 'metrology' / 'data')
metro = [os.path.join(os.path.dirname(sys.executable), 'metro')]
from measure_io_floor import READ  # noqa: E402
EVERY = FLOOR.replace(READ, "columns=None")  # every column read (the contract before metro left its unused inputs unread)
wing = [*metro, '-q', 'measure', f'{W}/wing50.parquet', '--layout', f'{D}/measured/nominal.toml', '--out', f'{W}/o_w.parquet']
cmds = {'baseline': [sys.executable, '-c', BASELINE, LOG, LAY, f'{W}/o_base.parquet'],
        'fail': [*metro, '-q', 'measure', LOG, '--layout', LAY, '--out', f'{W}/o_fail.parquet', '--tolerance-deg', '0.1'],
        'conform': [*metro, '-q', 'measure', LOG, '--layout', LAY, '--out', f'{W}/o_conf.parquet', '--tolerance-deg', '10'],
        'floor': [sys.executable, '-c', FLOOR, LOG, LAY, f'{W}/o_floor.parquet'],
        'floor_every_column': [sys.executable, '-c', EVERY, LOG, LAY, f'{W}/o_floor2.parquet'],
        'nopanel': wing,
        'panel': [*wing, '--panel', f'{D}/panels/wing.stl', '--points', f'{D}/panels/wing.holes.csv']}
rounds = int(sys.argv[2]); out = sys.argv[3]
def cpu(c):
    r = subprocess.run([sys.executable, '-c', RUN, *c], capture_output=True, text=True, check=True, env=_ENV)
    dt, kb, rc, t = r.stdout.split(); assert int(rc) in (0, 1), (c, rc); return float(t)
for c in cmds.values(): cpu(c)
res = []
for k in range(rounds):
    l0 = os.getloadavg()[0]
    t = {n: cpu(c) for n, c in cmds.items()}
    t['load'] = (l0, os.getloadavg()[0]); t['utc'] = time.strftime('%H:%M:%S', time.gmtime())
    for n in ('fail', 'conform', 'floor', 'floor_every_column'):
        t[f'{n}/baseline'] = t[n] / t['baseline']
    t['panel/nopanel'] = t['panel'] / t['nopanel']
    res.append(t)
    print(json.dumps(t), flush=True)
    json.dump(res, open(out, 'w'), indent=1)
