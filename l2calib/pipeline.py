"""Calibration data from a recipe and recordings: read → select → reference.

Each stage is one call so the CLI can show progress between them and tests can enter anywhere
(e.g. with in-memory simulated sequences instead of bags). Training on the prepared data:
:mod:`l2calib.training`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from l2calib.data import Segment
from l2calib.data import Sequence as DataSequence
from l2calib.errors import DataError, ReferenceLostTrackError
from l2calib.interfaces import ReferenceTrajectory
from l2calib.recipe import PluginChoice, Recipe

log = logging.getLogger("l2calib")


@dataclass
class PreparedData:
    """Everything the training needs, computed once."""

    sequences: list[DataSequence]
    segments: list[Segment]
    references: list[ReferenceTrajectory]
    selection: Any | None = None
    notes: list[str] = field(default_factory=list)
    #: LiDAR–IMU offset (s) where the references' |ω| follows the gyro (set by training)
    rate_offset_s: float | None = None

    def identity(self) -> list[str]:
        """Names and spans of the segments (part of the resume fingerprint)."""
        return [f"{s.name}:{s.start_ns}-{s.end_ns}:{len(s.measurements)}" for s in self.segments]

    @property
    def time_offset_hint_s(self) -> float | None:
        """The LiDAR–IMU offset (s) the data suggests, or ``None``.

        The median of the references' clock checks (see interfaces), else the rate
        correlation's :attr:`rate_offset_s`.
        """
        hints = [r.time_offset_hint_s for r in self.references if r.time_offset_hint_s is not None]
        return float(np.median(hints)) if hints else self.rate_offset_s


def time_offset_bound_s(recipe: Recipe) -> float | None:
    """The policy's ``time_offset_bound_s`` (s) with its plugin default; ``None``: unbounded."""
    from l2calib.plugins import get_plugin

    spec = get_plugin("l2calib.policies", recipe.policy.name)
    return getattr(spec.config.model_validate(recipe.policy.options), "time_offset_bound_s", None)


def read_sequences(recipe: Recipe, bags: Sequence[Path], progress: bool = False):
    """Opens the bags as sequences with the recipe's topics and conventions."""
    from l2calib.io.sequences import open_sequences

    return open_sequences([Path(b) for b in bags], recipe.data, progress=progress)


def select_segments(
    recipe: Recipe,
    sequences: Sequence[DataSequence],
    note: Callable[[str], None] | None = None,
):
    """Segments to calibrate on: the selection's windows, or every sequence whole.

    On planar, yaw-dominant motion (a ground vehicle) the selection keeps more data in longer
    windows (:func:`l2calib.selection.planar.planar_selection`; ``note`` is told so).

    Raises:
        DataError: no window is eligible (the message names the gaps, dropped scans and still
            periods that rule them out), or, with the selection disabled, an IMU gap inside a
            recording (named with its topic, time and length).
    """
    from l2calib.selection.gaps import check_imu_gaps_whole, no_window_reason

    if not recipe.selection.enabled:
        check_imu_gaps_whole(sequences)
        return [seq.segment() for seq in sequences], None
    from l2calib.selection.greedy import select_windows
    from l2calib.selection.planar import planar_selection

    config, why = planar_selection(
        recipe.selection, recipe.train.planar_min_yaw_share, [seq.imu for seq in sequences]
    )
    if why is not None and note is not None:
        note(why)
    selection = select_windows(sequences, config)
    if not selection.chosen:
        window = selection.config.window_s
        raise DataError(
            "the data selection found no window to calibrate on (each is still or spans a gap): "
            + no_window_reason(sequences, selection.windows, window),
            fix=f"record at least {window:g} s of motion free of gaps (check the drivers for "
            "dropped messages), lower selection.window_s, or set selection.enabled=false",
        )
    return selection.segments(sequences), selection


def compute_references(
    recipe: Recipe,
    segments: Sequence[Segment],
    sequences: Sequence[DataSequence] | None = None,
    note: Callable[[str], None] | None = None,
    progress: bool = False,
) -> list[ReferenceTrajectory]:
    """Runs the recipe's reference plugin on the segments (its fallback if it loses track).

    Where the reference loses track on some segments but not all, those segments are dropped
    (named in a note) and the references of the others returned; where it loses track on
    every segment, the recipe's fallback computes them all.

    Args:
        recipe: The resolved recipe (``reference`` and ``data`` sections are used).
        segments: Selected segments.
        sequences: The sequences the segments were cut from: LiDAR-odometry references start
            ``margin_s`` before each segment on their scans (warm-up).
        note: Called with a message for the user when segments are dropped or the fallback
            takes over.
        progress: Let the reference show progress bars (LiDAR odometry, per segment).

    Returns:
        One reference per kept segment, in order (``ref.segment`` names it).

    Raises:
        ReferenceLostTrackError: if the reference loses track on every segment and the recipe
            has no fallback.
    """
    from l2calib.plugins import get_plugin
    from l2calib.selection.planar import planar_motion

    # a ground vehicle's drive (from the IMU's rates): ct-lidar then adds its backward pass
    planar = planar_motion([s.imu for s in segments]).planar(recipe.train.planar_min_yaw_share)

    def compute(choice: PluginChoice) -> list[ReferenceTrajectory]:
        source = get_plugin("l2calib.references", choice.name).build(
            choice.options,
            data=recipe.data,
            sequences=sequences,
            progress=progress,
            # a known offset: a shift the clock check finds is that offset, not a file clock
            estimate_time_offset=recipe.train.estimate_time_offset
            or recipe.train.known_time_offset_s is not None,
            time_offset_bound_s=time_offset_bound_s(recipe),
            planar_motion=planar,
        )
        for msg in getattr(source, "notes", []) if note is not None else []:
            note(msg)
        return source.compute(list(segments))

    fallback = recipe.reference.fallback
    try:
        refs = compute(recipe.reference)
    except ReferenceLostTrackError as exc:
        if exc.tracked:  # lost on some segments only: those go, the rest is calibrated on
            msg = (
                f"segment(s) {', '.join(exc.lost)} dropped: {exc.message}; calibrating on the "
                f"{len(exc.tracked)} other(s)"
            )
            log.warning(msg)
            if note is not None:
                note(msg)
            return exc.tracked
        if fallback is None:
            raise
        msg = (
            f"the {recipe.reference.name} reference failed ({exc.message}); the recipe's "
            f"fallback, {fallback.name}, is used instead"
        )
        log.warning(msg)
        if note is not None:
            note(msg)
        refs = compute(fallback)
    if any(r.constrains == "position" for r in refs):
        log.info("the reference constrains positions only: the reward's rotation term is dropped")
    return refs


def kept_segments(segments: Sequence[Segment], refs: Sequence[ReferenceTrajectory]) -> list:
    """The segments that have a reference (one dropped where the reference lost track)."""
    names = {r.segment for r in refs}
    return [s for s in segments if s.name in names]


def prepare_data(
    recipe: Recipe,
    bags: Sequence[Path] | None = None,
    sequences: Sequence[DataSequence] | None = None,
    stage: Callable[[str], None] | None = None,
) -> PreparedData:
    """Reads (or takes) sequences, selects segments and computes their references."""
    data = select_data(recipe, bags=bags, sequences=sequences, stage=stage)
    return add_references(recipe, data, stage=stage)


def select_data(
    recipe: Recipe,
    bags: Sequence[Path] | None = None,
    sequences: Sequence[DataSequence] | None = None,
    stage: Callable[[str], None] | None = None,
) -> PreparedData:
    """Reads (or takes) sequences and selects segments, without references yet.

    ``calibrate`` judges the selected data (:func:`l2calib.assess.status.before_training`) before it
    spends anything on a reference; :func:`add_references` completes the data.
    """
    say = stage or (lambda _msg: None)
    if sequences is None:
        say("reading recordings")
        sequences = read_sequences(recipe, bags or [])
    say("selecting informative data")
    notes: list[str] = []
    segments, selection = select_segments(recipe, sequences, notes.append)
    return PreparedData(list(sequences), segments, [], selection, notes)


def add_references(
    recipe: Recipe, data: PreparedData, stage: Callable[[str], None] | None = None
) -> PreparedData:
    """Computes the references of ``data``'s segments (in place); returns ``data``."""
    say = stage or (lambda _msg: None)
    say(f"computing the {recipe.reference.name} reference")
    data.references = compute_references(recipe, data.segments, data.sequences, data.notes.append)
    data.segments = kept_segments(data.segments, data.references)
    if data.time_offset_hint_s is not None and recipe.train.known_time_offset_s is None:
        data.notes.append(
            f"the {recipe.reference.name} reference's clock check measured a LiDAR–IMU time "
            f"offset of {1000 * data.time_offset_hint_s:+.1f} ms (t_imu = t_lidar + offset): "
            "the offset starts from it (where the rotation rates agree, it is held there)"
        )
    return data
