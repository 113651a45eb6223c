"""Pose-based visual servoing of a moving object: the paper's Eq. (5)–(6) with the safety around it.

Split as ViSP splits ``vpServo`` from ``vpRobot``: :mod:`~evservo.control.pose_filter` (the tracker's
poses → the object's world pose and motion), :mod:`~evservo.control.law` (Eq. 5–6 and the
feed-forward reference), :mod:`~evservo.control.saturation` (limits and braking), composed by
:class:`~evservo.control.pbvs.Pbvs`.
"""

from evservo.control.law import pose_error
from evservo.control.pbvs import Pbvs, PbvsCommand, State
from evservo.control.pose_filter import PoseFilter, TwistEstimator

__all__ = ["Pbvs", "PbvsCommand", "PoseFilter", "State", "TwistEstimator", "pose_error"]
