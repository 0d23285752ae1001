"""Numbers published in the paper (Chen et al., Sensors 2018), verbatim.

These are inputs (Tables 1, 2, 5, 6) and reported results (Tables 3, 4, 7, 8) used only
for side-by-side display; nothing in metro is tuned to match the results.
"""

from __future__ import annotations

import numpy as np

from metrology.core.layout import SensorLayout

#: Table 1: theoretical simulated plane (A, B, C, D), the paper's sign
TABLE1_PLANE = np.array([0.0173, -0.3071, 0.9515, 34.1218])
#: Table 1: the paper's fitted plane
TABLE1_FITTED = np.array([0.0173, -0.3070, 0.9516, 34.1285])

#: Table 2: nominal zero points (mm) and directions, and the simulated errors
TABLE2_NOMINAL = np.array([
    [50.0, 0.0, 0.0, -0.5, 0.0, -0.8660],
    [0.0, 50.0, 0.0, 0.0, -0.5, -0.8660],
    [-50.0, 0.0, 0.0, 0.5, 0.0, -0.8660],
    [0.0, -50.0, 0.0, 0.0, 0.5, -0.8660],
])
TABLE2_ERRORS = np.array([
    [1.3, 0.9, 1.1, 0.0445, 0.0506, -0.0228],
    [1.3, -1.4, 1.6, -0.0634, 0.0479, -0.0237],
    [1.3, -1.2, 1.2, -0.0507, -0.0365, -0.0266],
    [1.5, 1.1, 1.4, 0.0339, -0.0682, -0.0353],
])

#: Table 5: fitted datum plane in the tracker frame (A, B, C, D)
TABLE5_PLANE = np.array([0.4497, 0.8932, -0.0084, -1690.2827])

#: Table 6: nominal parameters and the errors the paper's EKF estimated
TABLE6_NOMINAL = np.array([
    [-36.4655, 36.4655, -35.0, 0.3536, -0.3536, 0.8660],
    [36.4655, 36.4655, -35.0, -0.3536, -0.3536, 0.8660],
    [36.4655, -36.4655, -35.0, -0.3536, 0.3536, 0.8660],
    [-36.4655, -36.4655, -35.0, 0.3536, 0.3536, 0.8660],
])
TABLE6_ERRORS = np.array([
    [0.4838, -0.2460, 0.1723, 0.0047, -0.0065, -0.0047],
    [-0.2906, -0.4338, -0.2393, -0.0048, -0.0012, -0.0026],
    [0.9513, 0.5488, 0.1860, -0.0278, -0.0201, -0.0039],
    [0.5558, -0.8081, 0.1186, 0.0229, -0.0182, -0.0026],
])

#: Tables 3 and 7: measurements to convergence of the paper's EKF, per sensor
TABLE3_CONVERGENCE = (75, 86, 91, 81)
TABLE7_CONVERGENCE = (39, 44, 34, 44)
#: Tables 4 and 8: angular deviation of the normal (max, mean, std), deg
TABLE4 = {"before": (1.6801, 1.3387, 0.1841), "method1": (0.4278, 0.2446, 0.1024), "ekf_paper": (0.0511, 0.0412, 0.0057)}
TABLE8 = {"before": (0.6113, 0.5434, 0.0432), "method1": (0.4487, 0.2192, 0.1270), "ekf_paper": (0.1780, 0.1048, 0.0443)}

#: EKF settings of the paper: section 5 step 7 (simulation) and section 6 (experiment).
#: Section 3.2 states R = 1e-4 for the method; the simulation uses 8e-5.
EKF_PRESETS = {
    "simulation": {"Q": 1e-10, "R": 8e-5, "delta": 1e-4},
    "experiment": {"Q": 1e-12, "R": 9e-6, "delta": 1e-4},
}

NAMES = ("L1", "L2", "L3", "L4")


def layout_from_table(table, noise_mm=None) -> SensorLayout:
    """A :class:`SensorLayout` from rows ``(x, y, z, m, n, q)`` (directions normalised)."""
    table = np.asarray(table, dtype=float)
    noise = None if noise_mm is None else np.full(len(table), float(noise_mm))
    return SensorLayout(NAMES[: len(table)], table[:, :3], table[:, 3:], noise)


def table2_layouts():
    """(nominal, true) layouts of the simulation (Table 2)."""
    return layout_from_table(TABLE2_NOMINAL), layout_from_table(TABLE2_NOMINAL + TABLE2_ERRORS)


def table6_layouts():
    """(nominal, 'true') layouts of the experiment (Table 6: the paper's estimate as truth)."""
    return layout_from_table(TABLE6_NOMINAL), layout_from_table(TABLE6_NOMINAL + TABLE6_ERRORS)
