"""Odometry backends for l2calib (entry-point group ``l2calib.backends``)."""

from __future__ import annotations

from l2calib.interfaces import CandidateStatus, CandidateTrajectories, OdometryBackend

__all__ = ["CandidateStatus", "CandidateTrajectories", "OdometryBackend"]
