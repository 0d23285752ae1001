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
