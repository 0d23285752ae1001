"""Why the held-out test of a located step re-locates it on each fold (issue 30): a Monte Carlo on white noise.

    python benchmarks/study_shift_selection.py [--series 1000000] [--chunk 100000] [--seed 1]

Null series of 139 readings (white noise, a mean as the base model: the seed-35 null's length),
5 interleaved folds. The step is placed by the change-point search of
:class:`metrology.core.effects.Shift` (the split with the largest sum-of-squares reduction, at
least 7 poses each side), the in-sample F-test Bonferroni-split over the positions searched. Of
the series that pass it, printed: how many also pass the held-out gain test (one-sided paired
t, 5 %) when the step is placed on all poses (the held-out poses helped choose it) and when each
fold places it on its training poses only (what ``Shift.select`` does), and the joint rates of
both tests. A self-contained model of the tests (numpy and scipy only), not the diagnosis code.
"""
import argparse

import numpy as np
from scipy import stats

m, K = 139, 5
def best_split(r):  # r (N, q): returns k (N,) count before, gain
    q = r.shape[1]
    rs = r - r.mean(1, keepdims=True)
    tail = np.cumsum(rs[:, ::-1], 1)[:, ::-1]
    ms = max(3, int(np.ceil(0.05 * q)))
    ks = np.arange(ms, q - ms + 1)
    g = tail[:, ks] ** 2 * q / (ks * (q - ks))
    j = np.argmax(g, 1)
    return ks[j], g[np.arange(len(r)), j], len(ks)
def heldout_p(r, loc_all, relocate):
    N = r.shape[0]
    diff = np.zeros((N, m))
    t = np.arange(m)
    for f in range(K):
        test = t[f::K]; train = np.setdiff1d(t, test)
        rt = r[:, train]
        if relocate:
            kt, _, _ = best_split(rt)
            at = train[kt]  # first training pose after the step (time = index)
        else:
            at = loc_all
        after_tr = train[None, :] >= at[:, None]
        mb = rt.mean(1)
        n_a = after_tr.sum(1); n_b = len(train) - n_a
        mean_a = (rt * after_tr).sum(1) / np.maximum(n_a, 1)
        mean_b = (rt * ~after_tr).sum(1) / np.maximum(n_b, 1)
        after_te = test[None, :] >= at[:, None]
        pred_e = np.where(after_te, mean_a[:, None], mean_b[:, None])
        rte = r[:, test]
        diff[:, test] = (rte - mb[:, None]) ** 2 - (rte - pred_e) ** 2
    mu = diff.mean(1); sd = diff.std(1, ddof=1)
    tt = mu / (sd / np.sqrt(m))
    return stats.t.sf(tt, m - 1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", type=int, default=1_000_000)
    ap.add_argument("--chunk", type=int, default=100_000)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args(argv)
    rng = np.random.default_rng(a.seed)
    rows, done = [], 0
    while done < a.series:
        n = min(a.chunk, a.series - done)
        r = rng.normal(size=(n, m))
        k, g, nk = best_split(r)
        ss = ((r - r.mean(1, keepdims=True)) ** 2).sum(1)
        F = g / ((ss - g) / (m - 2))
        p_in = np.minimum(1, stats.f.sf(F, 1, m - 2) * nk)
        sel = p_in < 0.01
        rr = r[sel]
        rows.append(np.column_stack([p_in[sel], heldout_p(rr, k[sel], False), heldout_p(rr, None, True)]))
        done += n
    R = np.vstack(rows)
    print(f"{a.series} null series of {m} readings, {K} folds (seed {a.seed})")
    for thr in (0.01, 1e-3, 2.7e-4):
        s = R[:, 0] < thr
        print(f"in-sample p < {thr:g}: {s.sum() / a.series:.2e} of the series; of those, held-out p < 0.05 with the "
              f"step placed on all poses {np.mean(R[s, 1] < 0.05):.3f}, re-located per fold {np.mean(R[s, 2] < 0.05):.3f}; "
              f"both tests: {np.sum(s & (R[:, 1] < 0.05)) / a.series:.2e} and {np.sum(s & (R[:, 2] < 0.05)) / a.series:.2e}")


if __name__ == "__main__":
    main()
