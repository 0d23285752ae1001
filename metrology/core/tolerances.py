"""Numerical tolerances, in one place, each with its unit."""

#: smallest |cos| of the angle between a beam and a plane normal for which the beam is
#: taken to intersect the plane (unitless cosine; 1e-6 is a beam 89.99994 deg off the normal)
BEAM_PARALLEL_COS = 1e-6

#: a direction vector is "unit" within this (unitless, on the norm)
UNIT_NORM = 1e-6

#: a quaternion read from a file is accepted as unit within this (unitless, on the norm);
#: it is then normalised
QUATERNION_NORM = 1e-3

#: relative singular value below which a parameter combination is called unidentifiable
#: (unitless, on singular values of the column-scaled Jacobian)
RANK_RTOL = 1e-8

#: relative singular value below which a combination is called weakly identifiable
WEAK_RTOL = 1e-3

#: a point cloud whose second singular value is below this fraction of its first is
#: collinear (unitless)
COLLINEAR_RTOL = 1e-9

#: correlations between two fitted parameters are reported above this |r| (unitless): in
#: ``metro calibrate``'s JSON and in the fit reports of ``calibrate`` and ``diagnose``
#: (text and HTML). lmfit's default (0.1) lists every pair of these fits; above 0.5 one
#: parameter can trade for the other. On a small tilt range the beam's pivot (zero point
#: across the beam against its tilt) puts all pairs of x, y, tilt_e1, tilt_e2 above 0.95:
#: the identifiability line names that one combination
CORRELATION_REPORT = 0.5

#: variance inflation factors above this are reported as poorly separated parameters
#: (unitless; the standard error is more than sqrt(10) = 3.2 times what it would be if the
#: pose set decoupled the parameter: the usual rule of thumb). Informational: the pivot of
#: a beam about its spot gives VIFs in the thousands for any pose set a 20 mm range allows,
#: so warnings are raised on the standard errors against the target instead
VIF_WARN = 10.0

#: default wanted 1-sigma of a calibrated zero point (mm) and beam tilt (deg): either
#: alone, uncompensated, would tilt the measured normal by about 0.05 deg over the ~50 mm
#: between opposite spots, a tenth of the 0.5 deg drilling requirement of the paper
TARGET_ZERO_MM = 0.05
TARGET_TILT_DEG = 0.05

#: the drilling requirement on the normal: the angle between the measured normal and the
#: true one (deg; the paper's 0.5 deg). ``metro validate`` and ``metro normals`` judge
#: against it by default (``--tolerance-deg``)
DRILLING_TOLERANCE_DEG = 0.5

