"""Where the LiDAR–IMU time offset comes from before PPO: the rate correlation, held or a start.

The references' ``|ω|`` against the gyro (:func:`~l2calib.time_offset_estimate.
offset_from_references`) pins the offset on hand-held data to ~0.02 ms of the truth on the
simulator's recordings, while estimating it jointly with the extrinsic ended 0.1-0.3 ms early on
every LiDAR-only row and cost the extrinsic 0.3-0.6 cm against the same recording with the IMU
re-stamped (the offset known; docs/time_offset.md, benchmarks/results/time_offset.md). So where
that correlation is sharp, ``train.time_offset_from_rates: hold`` (the default) keeps the offset
there (``train.known_time_offset_s``, 7-dim actions) and PPO searches the extrinsic alone; the
offset's resolution probe still runs at the held value and says whether the reward agrees.
Where the correlation is flat or weak (uav cruising, ground vehicles) the offset is estimated
jointly, started from the correlation when it is observable at all.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from l2calib.pipeline import PreparedData, time_offset_bound_s
from l2calib.recipe import Recipe

#: Least peak sharpness (:class:`~l2calib.time_offset_estimate.OffsetEstimate`) at which the
#: offset is held: the simulator's hand-held ct-lidar and gt references gave 12-100, uav flights
#: below the observability floor (1.0); 5 leaves a margin on both sides.
HOLD_MIN_SHARPNESS = 5.0
#: Least peak correlation at which the offset is held.
HOLD_MIN_CORRELATION = 0.95
#: Largest disagreement (s) with a given start (the recipe's ``init_time_offset_s``, a
#: reference's clock check) at which the correlation is held.
HOLD_MAX_HINT_GAP_S = 0.002


def offset_start_s(train: Any, hint_s: float | None) -> float | None:
    """The time offset's starting mean (s), ``None`` when it is not estimated (or from 0).

    The recipe's ``train.init_time_offset_s`` (the user's, e.g. from ``inspect``) wins over the
    reference's clock-check hint ``hint_s``.
    """
    if not train.estimate_time_offset:
        return None
    start = hint_s if train.init_time_offset_s is None else train.init_time_offset_s
    return None if start is None else float(start)  # numpy scalars would not reach the YAML


def offset_from_rates(
    recipe: Recipe, data: PreparedData, say: Callable[[str], None]
) -> tuple[Recipe, str | None]:
    """The recipe training runs with, and how its time offset is found (``None``: not at all).

    Sets ``data.rate_offset_s`` (the joint estimation's start) where the correlation is
    observable and nothing else starts the offset; returns the recipe with the offset held
    (``estimate_time_offset: false``, ``known_time_offset_s``) where it is sharp and
    ``train.time_offset_from_rates`` is ``hold``. The recipe's ``init_time_offset_s`` (the user's
    start) and a reference's clock check start the joint estimation instead where the
    correlation disagrees with them by more than :data:`HOLD_MAX_HINT_GAP_S`.

    Returns:
        ``(recipe, method)``: ``method`` is written to ``calibration.yaml`` → ``time_offset``.
    """
    from l2calib.time_offset_estimate import offset_from_references

    train = recipe.train
    if train.known_time_offset_s is not None:
        return recipe, "known: held at the recipe's train.known_time_offset_s"
    if not train.estimate_time_offset:
        return recipe, None
    joint = "estimated jointly with the extrinsic"
    # a start given by the user (e.g. from `inspect`) or by a reference's clock check
    given, where = train.init_time_offset_s, "the recipe's train.init_time_offset_s"
    if given is None and data.time_offset_hint_s is not None:
        given, where = data.time_offset_hint_s, "the reference's clock check"
    bound = time_offset_bound_s(recipe) or 0.2
    est = offset_from_references(data.references, data.segments, data.sequences, bound)
    if est is None:
        start = where if given is not None else "0"
        return recipe, f"{joint} (the rotation rates do not pin it), from {start}"
    quality = f"correlation {est.correlation:.3f}, sharpness {est.sharpness:.1f}"
    sharp = est.sharpness >= HOLD_MIN_SHARPNESS and est.correlation >= HOLD_MIN_CORRELATION
    agrees = given is None or abs(given - est.time_offset_s) <= HOLD_MAX_HINT_GAP_S
    if train.time_offset_from_rates == "hold" and sharp and agrees:
        msg = (
            f"the references' rotation rate follows the gyro at a LiDAR-IMU offset of "
            f"{1000 * est.time_offset_s:+.2f} ms (t_imu = t_lidar + offset; {quality}): the "
            "offset is held there and PPO searches the extrinsic alone "
            "(train.time_offset_from_rates: start estimates it jointly)"
        )
        data.notes.append(msg)
        say(msg)
        value = float(est.time_offset_s)  # a plain float in the recipe the workers receive
        held = train.model_copy(
            update={"estimate_time_offset": False, "known_time_offset_s": value}
        )
        method = f"held at the references' rotation-rate correlation with the gyro ({quality})"
        return recipe.model_copy(update={"train": held}), method
    if given is not None:
        if not agrees:
            msg = (
                f"the references' rotation rate puts the LiDAR-IMU offset at "
                f"{1000 * est.time_offset_s:+.2f} ms ({quality}), {where} at "
                f"{1000 * given:+.2f} ms: the offset is estimated jointly from the latter"
            )
            data.notes.append(msg)
            say(msg)
        return recipe, f"{joint}, from {where}"
    data.rate_offset_s = est.time_offset_s
    msg = (
        f"the references' rotation rate follows the gyro best at a LiDAR-IMU offset of "
        f"{1000 * est.time_offset_s:+.1f} ms (t_imu = t_lidar + offset; {quality}): the "
        "offset's estimation starts there"
    )
    data.notes.append(msg)
    say(msg)
    return recipe, f"{joint}, from the rotation-rate correlation ({quality})"
