"""Pose design: the calibration poses to take, chosen before any data exist (``metro plan``)."""

from metrology.plan.candidates import Limits, PoseSet, draw_candidates, feasible, perturb, pose_readings
from metrology.plan.design import covariance, exchange, greedy_order, log_det, pose_information, prior_information
from metrology.plan.extent import DatumExtent
from metrology.plan.plan import CRITERION, Design, PosePlan, design_for, plan_poses

__all__ = [
    "Limits", "PoseSet", "draw_candidates", "feasible", "perturb", "pose_readings",
    "covariance", "exchange", "greedy_order", "log_det", "pose_information", "prior_information",
    "DatumExtent", "CRITERION", "Design", "PosePlan", "design_for", "plan_poses",
]
