"""Judging a trained result: refinement, resolution probes, reference agreement, status.

:mod:`~l2calib.assess.result` holds the result type every stage fills in and
``calibration.yaml`` is written from.
"""
