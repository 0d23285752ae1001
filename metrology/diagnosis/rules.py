"""The decision rules of the diagnosis, in the order the engine applies them.

Each rule is a named function with its threshold beside it and the reason in one line. The
engine (:mod:`~metrology.diagnosis.select` and :mod:`~metrology.diagnosis.members` for the
selection, :mod:`~metrology.diagnosis.judge`, :mod:`~metrology.diagnosis.crosstalk` and
:mod:`~metrology.diagnosis.posevar` for the verdict) calls them by name; :data:`THRESHOLDS`, the levels the ``--json`` output
reports, is made of the same constants. The levels were set a priori and checked on null data
(``benchmarks/study_blind.py``; results in ``benchmarks/results/``). What each effect is (its
family, its size, what it can be mistaken for) is in the registry, :mod:`metrology.core.effects`;
numerical tolerances of the solvers are not decision rules and stay with them.

Order: gross readings (1), a candidate's significance (2), a step's choice (3-6), the selection's
stop and scope (7-9), the verdict: each cause needed (10), judged on its sensors (11), not
crosstalk (12), the random pose error (13), confidence (14-16), the datum cloud (17), the datum
plane (18), the open search beyond the catalogue (19-21), the catalogue against it (22).
"""

from __future__ import annotations

from metrology.diagnosis.results import Confidence, Outcome

__all__ = ["THRESHOLDS", "ALPHA_OUTLIER", "ALPHA_CANDIDATES", "ALPHA_HELDOUT", "ALPHA_ORDER", "ALPHA_BATTERY",
           "ALPHA_CONFOUND", "CORR_CONFOUND", "ALPHA_HIGH", "ALPHA_FORM", "LR_ONE_SENSOR", "MAX_CAUSES", "PRUNE_P",
           "MIN_POSES_COMPARED", "gross_level", "fits_in_sample", "significant", "in_sample_only", "better_held_out",
           "per_pose_imitates", "explains_sensors", "shows_something", "room_for_another", "fixed_explains_as_well",
           "needed_given_others", "crosstalk_better", "crosstalk_as_good", "random_pose_tried", "random_pose_significant",
           "random_pose_explains", "weak_evidence", "indistinguishable", "poorly_separated", "confidence_of_nothing", "confidence_of",
           "datum_agrees", "confidence_given_datum", "ALPHA_DATUM_PLANE", "DATUM_OFF_PRIOR_WIDEN",
           "datum_plane_off", "gross_given_others", "GROSS_RUN", "persists", "TAIL_REACH", "tails_not_gross", "MAX_EMPIRICAL", "search_tried",
           "search_in_sample", "search_tails_in_sample", "search_held_out", "room_for_another_term",
           "empirical_better", "empirical_as_good", "empirical_indistinguishable", "empirical_collinear", "rival_of_another_cause",
           "search_beside"]

# -- 1. gross readings ---------------------------------------------------------------------------
#: a reading is gross when its standardised residual is beyond this family-wise level over the readings
ALPHA_OUTLIER = 0.01


def gross_level(m: int) -> float:
    """The two-sided tail of one reading among ``m``: gross beyond ``norm.isf(gross_level(m))``."""
    return ALPHA_OUTLIER / (2 * m)


def gross_given_others(t_deleted: float, m: int) -> bool:
    """1. A flagged reading stays gross, once other causes are named, only where its deleted
    (externally studentised) residual under them is beyond the flagging level: ``t_deleted`` the
    reading's gross term over its standard error in the joint fit (the reading left out, the
    other causes fitted on the rest; a located step re-placed with the reading's pose on either
    side, the smaller taken), ``m`` the readings. Reason: a reading the other causes explain (the
    first pose of a warm-up before a drift was named, the pose just before a knock the change-point
    search placed one pose early) is not an outlier (issue 40); left out of the fit, a gross
    reading cannot be absorbed by a flexible cause (a refit with it in could)."""
    from scipy import stats

    return abs(float(t_deleted)) > float(stats.norm.isf(gross_level(max(int(m), 1))))


#: 1. a gross reading is one reading (a scratch, a dropped frame): this many consecutive readings of
#: one sensor (in pose order, blanks skipped) flagged with one sign are a step or a drift, not gross
GROSS_RUN = 3


def persists(run_length: int) -> bool:
    """1. A run of ``run_length`` consecutive flagged readings of one sensor, all of one sign, is not
    gross: it persists (a knock near the run's end, the first poses of a warm-up), and the ``shift``
    and ``drift`` candidates are scored on it. Reason: flagged as gross, the readings after a knock
    near the end were dropped, and with them the step that explains them (issue 54: a knock 9 poses
    before the end named ``outliers`` on 9 readings, and no ``shift``). Two gross readings in a row
    stay gross; three of one sign on one sensor among a run's few gross readings is not chance."""
    return int(run_length) >= GROSS_RUN


#: 1. a flagged reading within this many flagging thresholds may be the edge of the sensor's own noise
#: (a contaminated normal whose broad part is up to 3 times its core puts its largest of 150 readings
#: within ~3 x 3.4 = 10 core sigmas; the flagging threshold is 3.9-4.3 sigmas for 100-1000 readings)
TAIL_REACH = 3.0


def tails_not_gross(p_shape_rest: float, z_flagged_max: float, threshold: float) -> bool:
    """1. The readings flagged on one sensor are the tails of its noise, not gross, where the rest of
    its readings (the flagged left out) are heavier-tailed than a normal (the kurtosis test, one-sided,
    ``p_shape_rest < ALPHA_HELDOUT``, rule 21's shape level) and every flagged reading stands within
    ``TAIL_REACH`` flagging thresholds (``z_flagged_max`` the largest flagged ``|r| / s``, ``threshold``
    the flagging level in the same units). Reason: the ``outliers`` family claims isolated gross
    readings (a scratch, a dropped frame: a reading lost, its error unrelated to the noise's scale;
    the catalogue's are 0.1-2 mm on noise of microns) on noise otherwise normal; a heavy-tailed noise
    puts its largest readings just past the threshold and overpopulates the tail below it (issue 54:
    heavy-tailed noise named ``outliers`` high). Left unflagged, they are judged with every other
    reading by rule 21 (the residuals' distribution)."""
    return p_shape_rest < ALPHA_HELDOUT and z_flagged_max <= TAIL_REACH * threshold


# -- 2. a candidate is significant ----------------------------------------------------------------
#: family-wise level of the in-sample F-tests, Bonferroni-split over every candidate scored
ALPHA_CANDIDATES = 0.01
#: the one-sided held-out gain test that confirms the F-test (a fit in sample must predict new poses)
ALPHA_HELDOUT = 0.05


def fits_in_sample(p_insample: float, n_cand: int) -> bool:
    """The in-sample F-test passes at ``ALPHA_CANDIDATES`` split over the ``n_cand`` candidates."""
    return p_insample < ALPHA_CANDIDATES / n_cand


def significant(p_insample: float, p_heldout: float, n_cand: int, rms_reference: float, rms_extended: float) -> bool:
    """Both tests pass and the candidate's held-out RMS on its sensors is below the reference's."""
    return fits_in_sample(p_insample, n_cand) and p_heldout < ALPHA_HELDOUT and rms_reference > rms_extended


def in_sample_only(s, n_cand: int) -> bool:
    """A lead: fits in sample but does not predict held-out poses (too small or too confounded to name)."""
    return not s.significant and fits_in_sample(s.p_insample, n_cand)


# -- 3-6. a step's choice ---------------------------------------------------------------------------
#: a richer member (or a per-pose cause over a fixed one) must predict held-out poses better at this level
ALPHA_ORDER = 0.05


def better_held_out(p_better: float, n_tested: int = 1) -> bool:
    """3. A member replaces the one held only when it predicts held-out poses significantly better
    (the level split over the ``n_tested`` tried at once: a rung of the spline ladder)."""
    return p_better < ALPHA_ORDER / n_tested


def per_pose_imitates(p_per_pose_better: float) -> bool:
    """4. A per-pose cause is an imitation where the best fixed cause predicts held-out poses as well
    (an offset and two tilts a pose follow any effect smooth over a pose's spots)."""
    return not better_held_out(p_per_pose_better)


#: 5. the noise-model battery's family-wise level: residuals consistent with the stated noise
ALPHA_BATTERY = 0.01


def explains_sensors(p_battery: float) -> bool:
    """5. A member (or the joint model) explains its sensors: their residuals pass the battery."""
    return p_battery >= ALPHA_BATTERY


#: 6. after a step chose a cause on its own sensors, a family elsewhere is rescored only if a member showed this
PRUNE_P = 0.2


def shows_something(p_insample: float) -> bool:
    """6. A family showed something at a step (its members are rescored at the next)."""
    return p_insample < PRUNE_P


# -- 7-9. the selection's stop and scope --------------------------------------------------------------
#: 7. at most this many causes are named in one data set
MAX_CAUSES = 3


def room_for_another(n_chosen: int) -> bool:
    """7. The selection goes on while fewer than ``MAX_CAUSES`` causes are chosen."""
    return n_chosen < MAX_CAUSES


#: 8. the fewest poses (without a gross reading) on which two selections' held-out errors are compared
MIN_POSES_COMPARED = 3


def fixed_explains_as_well(p_per_pose_better: float, n_poses: int) -> bool:
    """8. A selection without per-pose causes is taken where the per-pose one does not predict held-out
    poses significantly better (the rule of 4 over the whole selection)."""
    return n_poses >= MIN_POSES_COMPARED and not better_held_out(p_per_pose_better)


# -- 10-13. the verdict ------------------------------------------------------------------------------
def needed_given_others(p_heldout_given_others: float, n_causes: int, drops_readings: bool = False) -> bool:
    """10. A cause is needed when its held-out gain given the others passes ``ALPHA_HELDOUT`` split over
    the causes (a later cause can make an earlier one redundant); gross readings predict nothing held
    out and are exempt."""
    return drops_readings or p_heldout_given_others < ALPHA_HELDOUT / max(n_causes, 1)


def crosstalk_better(p: float, n_others: int) -> bool:
    """12. Another sensor's distance predicts the characteristic significantly better: crosstalk,
    not the sensor's own (``ALPHA_HELDOUT`` split over the other sensors)."""
    return p < ALPHA_HELDOUT / n_others


#: 12, 15. a rival whose held-out gain cannot be told from the cause's at this level ties with it
ALPHA_CONFOUND = 0.05


def crosstalk_as_good(p_worse: float) -> bool:
    """12. Crosstalk predicts as well (not significantly worse): the cause is named, ambiguous, the rival
    listed (gain errors are common, crosstalk rare)."""
    return p_worse >= ALPHA_CONFOUND


#: 13. a random pose error's covariance must gain this much (twice the log-likelihood) over excess
#: variance on one sensor alone: a margin between non-nested models, not a test at a known level
LR_ONE_SENSOR = 3.84


def random_pose_tried(cause: str, confidence: Confidence) -> bool:
    """13. A random pose error is looked for only where the verdict is ``unexplained`` or ``partial``
    (structure left that no fixed cause took; with 3 sensors no rigid pose error can be fitted)."""
    return cause != Outcome.NONE and confidence not in (Confidence.HIGH, Confidence.MODERATE, Confidence.AMBIGUOUS)


def random_pose_significant(p: float, n_cand: int) -> bool:
    """13. The random pose error's test passes at ``ALPHA_CANDIDATES`` split over the candidates and itself."""
    return p < ALPHA_CANDIDATES / (n_cand + 1)


def random_pose_explains(tests_consistent: bool, p_explained: float, lr_one_sensor: float) -> bool:
    """13. The whitened residuals are noise on every sensor, and no single sensor's excess explains as much."""
    return tests_consistent and explains_sensors(p_explained) and lr_one_sensor >= LR_ONE_SENSOR


# -- 14-16. confidence --------------------------------------------------------------------------------
#: 14. confidence high only where every cause's held-out p given the others is below this
ALPHA_HIGH = 0.01


def weak_evidence(p_heldout_given_others: float) -> bool:
    """14. Named, but on a held-out p a null data set gives often enough for ``high`` to overclaim."""
    return not p_heldout_given_others < ALPHA_HIGH


def indistinguishable(p_separation: float) -> bool:
    """15. A runner-up of another family whose held-out gain cannot be told from the cause's."""
    return p_separation >= ALPHA_CONFOUND


#: 15. |correlation| of a component parameter with a base parameter beyond which it is poorly separated
CORR_CONFOUND = 0.95


def poorly_separated(correlation: float) -> bool:
    """15. A parameter of the cause too correlated with the base geometry to be told from it."""
    return correlation > CORR_CONFOUND


def confidence_of_nothing(consistent: bool, has_lead: bool) -> Confidence:
    """16. Nothing named: ``moderate`` where the residuals are noise and nothing fits even in sample
    (no effect above the detectable sizes; smaller ones are not ruled out), else ``low``."""
    return Confidence.MODERATE if consistent and not has_lead else Confidence.LOW


def confidence_of(consistent: bool, weak: bool, confounded: bool) -> Confidence:
    """16. ``partial`` where structure remains, else ``moderate`` on weak evidence, else ``high``; either
    becomes ``ambiguous`` where something the data cannot separate is said."""
    if not consistent:
        return Confidence.PARTIAL
    return Confidence.AMBIGUOUS if confounded else (Confidence.MODERATE if weak else Confidence.HIGH)


# -- 17. the datum cloud ---------------------------------------------------------------------------------
#: the datum cloud's form disagrees with the readings' below this level
ALPHA_FORM = 0.01


def datum_agrees(p: float) -> bool:
    """17. The readings see the form the tracker scanned."""
    return p >= ALPHA_FORM


def confidence_given_datum(confidence: Confidence, cause: str, agrees: bool) -> Confidence:
    """17. ``low`` where the datum cloud disagrees and the verdict rests on the datum (nothing named, or
    its form named): the inputs contradict each other there; a cause of the head keeps its confidence."""
    return Confidence.LOW if not agrees and cause in (Outcome.NONE, "plane_form") else Confidence(confidence)


# -- 18. the datum plane against its scan's covariance (issue 40), given the causes named (issue 54) --
#: the datum plane the readings place (estimated with the sensors under the scan's covariance) is
#: off the scan's plane by more than the scan's stated uncertainty when the innovation test's p is
#: below this: first against the base model (a screen), then, where the screen finds it off, given
#: the causes the diagnosis named (:mod:`metrology.diagnosis.planegiven`: their parameters and, for a
#: random pose error, its covariance in the null; an unmodelled effect leaks into the plane, issue 54). Reason: the null's budget of false causes (1 %) is left to the catalogued causes; a
#: plane honestly scanned is named off once in 1000 runs.
ALPHA_DATUM_PLANE = 1e-3


#: a plane off its scan: the scan's covariance is not trusted, and the plane is placed by the readings
#: under a prior this many times wider (1 sigma). Reason: held at the scan's prior, the plane comes
#: back only part of the way and the rest is read as a pose error; without any prior the offset,
#: which the zero points nearly absorb, is not bounded.
DATUM_OFF_PRIOR_WIDEN = 100.0


def datum_plane_off(p: float) -> bool:
    """18. The plane the readings place is off the scan's by more than its stated uncertainty
    (named as the datum's, ``datum_tilt``, not read as a pose error; beside the causes named, after
    them: the headline is the cause of the largest held-out gain)."""
    return p < ALPHA_DATUM_PLANE


# -- 19-21. the open search beyond the catalogue (issue 54; metrology.diagnosis.search) -------------
#: 19. at most this many empirical terms (as ``MAX_CAUSES`` causes)
MAX_EMPIRICAL = 3


def search_tried(cause: str, confidence) -> bool:
    """19. The vocabulary is searched where the residuals stay inconsistent with the noise: the verdict
    ``unexplained``, or a cause named that leaves structure (``partial``); and where a cause is named
    that the data cannot tell from a rival (``ambiguous``: rules 12, 15, 22), on the base residuals,
    its terms said beside the cause (the rival's variables; issue 54: an incidence-times-distance
    effect named ``scale``, crosstalk tying, was never searched). Reason: elsewhere the catalogue
    explains the data, and a search run on every data set would spend the nulls' budget."""
    return cause == Outcome.UNEXPLAINED or Confidence(confidence) in (Confidence.PARTIAL, Confidence.AMBIGUOUS)


def search_beside(confidence, rival_ties: bool = False) -> bool:
    """19. The search runs on the base residuals, its terms beside the cause and not in the model, where
    the cause is ``ambiguous``, or a rival outside the catalogue ties with a cause named
    (``rival_ties``: crosstalk, rule 12, or a term, rule 22; the verdict may be ``partial``): the
    rival predicts as well as the cause, so what the search should name is what the cause's fit
    took, not only the structure left beside it."""
    return rival_ties or Confidence(confidence) == Confidence.AMBIGUOUS


def search_in_sample(p: float, m: int) -> bool:
    """19. A term passes in sample at ``ALPHA_CANDIDATES / m``, ``m`` its share of the search's
    multiplicity (:func:`metrology.diagnosis.search.multiplicity`: split over the sensors, the
    variables and each variable's terms; a weighted Bonferroni, so the search's family-wise level is
    the catalogue's)."""
    return p < ALPHA_CANDIDATES / max(int(m), 1)


def search_tails_in_sample(p_scatter: float, n_sensors: int, p_shape: float) -> bool:
    """21. The residuals' tails: their scatter beyond the stated noise (chi-square) at
    ``ALPHA_CANDIDATES`` split over the sensors, and their shape heavier than a normal's (the
    kurtosis test, one-sided) at ``ALPHA_HELDOUT``. Reason: the distribution is one hypothesis a
    sensor, not a term of the vocabulary (split over the ~3000 terms, a tail that lifts the
    chi-square far beyond the battery's level is not seen in 30-150 readings); the shape alone is
    weak in so few readings, the stated noise is the core's scale; noise merely understated is
    normal (its kurtosis 3). The held-out test (rule 20's level) guards the nulls' budget
    (``benchmarks/study_outside.py --nulls``)."""
    return p_scatter < ALPHA_CANDIDATES / max(int(n_sensors), 1) and p_shape < ALPHA_HELDOUT


def search_held_out(p: float, gain: float) -> bool:
    """20, 21. The term predicts held-out poses better, at the catalogue's ``ALPHA_HELDOUT``."""
    return p < ALPHA_HELDOUT and gain > 0


def empirical_better(p: float, n_compared: int) -> bool:
    """22. A term of the vocabulary, fitted in place of a cause named on one sensor, predicts its
    held-out poses significantly better (one-sided paired, at ``ALPHA_HELDOUT`` split over the terms
    compared; :mod:`metrology.diagnosis.rival`): the cause is not named (alone: ``unexplained``, and
    the search runs). Reason: a catalogued curve bends to an effect it does not describe; only as
    well, the cause stays (the catalogue's families are the common causes)."""
    return p < ALPHA_HELDOUT / max(int(n_compared), 1)


def empirical_as_good(gain: float, p_worse: float, k_term: int, k_cause: int) -> bool:
    """22. Not significantly better, but a term of fewer coefficients (``k_term < k_cause``) whose
    held-out gain over the cause is positive and which is not significantly worse (at
    ``ALPHA_CONFOUND``): the cause stays named, ``ambiguous``, the term said beside it (as rule 12's
    crosstalk tie). Reason: a simpler term outside the catalogue predicts the residual no worse, so
    the richer curve's flexibility, not its family, may be what fits; one of as many coefficients
    (a product of the cause's own variable with a near-constant) ties by chance half the time."""
    return gain > 0 and p_worse >= ALPHA_CONFOUND and k_term < k_cause


def empirical_indistinguishable(gain: float, k_term: int, k_cause: int, own_variable: bool) -> bool:
    """22. A term of a variable the cause's family does not follow (``own_variable`` False: none of the
    term's variables is one the family's curves are made of), of no more coefficients, that predicts
    the cause's held-out poses better, not significantly (``gain > 0``: it explains more of their
    variance): the cause stays named, ``ambiguous``, the term said beside it. Reason: rule 15 makes
    a catalogued family that predicts as well a confounder; a term of another variable is another
    family, outside the catalogue (a zero that follows ``dT/dt`` through a warm-up, where ``dT/dt``
    is nearly affine in ``T``, was named ``drift`` ``high``, issue 54). A term of the family's own
    variables (a product of the run's time with a near-constant, against a drift) is the cause in
    another dress and ties by chance half the time: only :func:`empirical_as_good` weighs it."""
    return not own_variable and k_term <= k_cause and gain > 0


def empirical_collinear(correlation: float, k_term: int, k_cause: int, own_variable: bool) -> bool:
    """22. A term of a variable the cause's family does not follow (``own_variable`` False), of as many
    coefficients, whose column the cause's columns reproduce (``correlation``: the multiple correlation
    of the term on the cause's columns and a constant, over the sensor's readings) at ``CORR_CONFOUND``
    or closer: the cause stays named, ``ambiguous``, the term said beside it, whichever predicts the
    held-out poses better. Reason: physics, not the fit: through a first-order warm-up the
    temperature's rate is affine in the temperature (``dT/dt = (T_end - T) / tau``), so a zero that
    follows the air-to-head gradient (``dT/dt``) and one that follows ``T`` are the same curve in
    that run; the measured ``T`` is the smoother column (the rate is its derivative, its noise
    amplified), so ``drift@temp`` wins held out whichever the head follows and was named ``high``
    on a rate effect (issue 54, dev seed 5501: |corr(T, dT/dt)| >= 0.997 on every such miss). The
    data cannot tell them apart; the verdict says so (rule 15's level). A cause of more coefficients
    (``drift@lag``: ``T - T_lag`` is close to ``tau dT/dt`` on any run) holds the term as one of its
    curves: the family's claim stands, and only rule 22's held-out comparisons weigh it."""
    return not own_variable and k_term == k_cause and abs(correlation) >= CORR_CONFOUND


def rival_of_another_cause(term_variables, other_causes_variables) -> bool:
    """22. A term that follows a variable another named cause's family is made of (``other_causes_variables``:
    :data:`metrology.diagnosis.rival.OWN_VARIABLES` of every other cause named) is not weighed against the
    cause. Reason: the comparison is made on the base residual, where the other causes' structure is still
    there; a term of their variable fits it, and "predicts the cause's poses better" by what the other cause
    explains (a datum form named beside a drift: a field over the plate beat ``drift@temp`` on its sensor,
    and the drift, right, was made ``ambiguous``; tests/diagnosis/test_select.py)."""
    return bool(set(term_variables) & set(other_causes_variables))


def room_for_another_term(n_found: int) -> bool:
    """19. The search goes on while fewer than ``MAX_EMPIRICAL`` terms are taken."""
    return n_found < MAX_EMPIRICAL


#: the levels (the ``thresholds`` of the ``--json`` output; the keys and their order are its schema)
THRESHOLDS = {
    "alpha_candidates": ALPHA_CANDIDATES,
    "alpha_heldout": ALPHA_HELDOUT,
    "alpha_battery": ALPHA_BATTERY,
    "alpha_outlier": ALPHA_OUTLIER,
    "alpha_confound": ALPHA_CONFOUND,
    "corr_confound": CORR_CONFOUND,
    "alpha_order": ALPHA_ORDER,
    "alpha_form": ALPHA_FORM,
    "alpha_high": ALPHA_HIGH,
    "lr_one_sensor": LR_ONE_SENSOR,
    "alpha_datum_plane": ALPHA_DATUM_PLANE,
    "gross_run": GROSS_RUN,
    "tail_reach": TAIL_REACH,
    "max_empirical": MAX_EMPIRICAL,
}
