import numpy as np

from metrology.core.sym2 import eig2, nuclear2, one_sign2


def test_the_closed_forms_are_their_eigenvalue_definitions():
    # one_sign2 and nuclear2 without the eigenvalues: against the definitions on the eigenvalues, both signs, one
    # sign, rank 1, zero, and entries over six decades
    rng = np.random.default_rng(3)
    a, b, c = rng.normal(size=(3, 20000)) * 10.0 ** rng.uniform(-3, 3, size=(3, 20000))
    a, b, c = (np.concatenate([x, y]) for x, y in ((a, [1.0, -2.0, 0.0, 4.0]), (b, [0.0, 0.0, 0.0, 2.0]),
                                                    (c, [3.0, -1.0, 0.0, 1.0])))
    l1, l2 = eig2(a, b, c)
    one = np.maximum(np.maximum(l1, 0) + np.maximum(l2, 0), -(np.minimum(l1, 0) + np.minimum(l2, 0)))
    nuc = np.abs(l1) + np.abs(l2)
    scale = np.abs(l1) + np.abs(l2) + 1e-300
    assert np.all(np.abs(one_sign2(a, b, c) - one) <= 1e-15 * scale)
    assert np.all(np.abs(nuclear2(a, b, c) - nuc) <= 1e-15 * scale)
    assert one_sign2(np.array([1.0]), np.array([0.0]), np.array([3.0]))[0] == 4.0  # both positive: the trace
    assert one_sign2(np.array([1.0]), np.array([0.0]), np.array([-3.0]))[0] == 3.0  # two signs: the larger side
    assert nuclear2(np.array([1.0]), np.array([0.0]), np.array([-3.0]))[0] == 4.0
