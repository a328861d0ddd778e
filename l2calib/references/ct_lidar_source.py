"""``ct-lidar`` reference: continuous-time LiDAR-only odometry of each segment.

The engine is :mod:`l2calib.references.ct_odometry`: every scan has its own smooth motion, so
aggressive hand-held motion that defeats KISS-ICP's constant-velocity deskew is followed (see
``docs/references.md`` for measured accuracy). Poses are written at ``poses_per_scan`` even
times in every scan (the first at the scan's first point) and at the last scan's latest point,
so the reference covers every point of the segment without extrapolation. Segments near each
other, or near their recording's start, are cut from one run that starts there
(:mod:`l2calib.references.ct_runs`); the others run one by one with the warm-up, per-segment
world frames (``ct-lidar:<segment>``) and disk cache of
:class:`~l2calib.references.odometry_source.LidarOdometryReference`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence as Seq
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, LidarScan, Segment
from l2calib.errors import ReferenceLostTrackError
from l2calib.interfaces import ReferenceTrajectory
from l2calib.references.cache import (
    alternative_from_arrays,
    cache_key,
    segment_fingerprint,
    trajectory_arrays,
    trajectory_from_arrays,
)
from l2calib.references.ct_motion import sample_poses
from l2calib.references.ct_odometry import CtLidarOdometry
from l2calib.references.ct_runs import OdometryRun, cut, plan_runs
from l2calib.references.odometry_source import LidarOdometryReference
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")

NAME = "ct-lidar"
ENGINE_VERSION = "10"  # bump when the odometry's results change, to invalidate cached references


def cold_starts(warmup: list[LidarScan], first_ns: int, options) -> list[int]:  # noqa: ANN001
    """Where the attempts start: indices into ``warmup`` (``len(warmup)``: no warm-up).

    The first ``margin_s`` before the segment's first scan (``first_ns``), each next one twice
    as far back, as far as the loaded scans reach; no index twice.
    """
    stamps = np.array([s.stamp_ns for s in warmup], np.int64)
    starts: list[int] = []
    for j in range(options.cold_starts):
        back_s = options.margin_s * 2**j
        i = int(np.searchsorted(stamps, first_ns - int(back_s * NS_PER_S)))
        if i not in starts:
            starts.append(i)
    return starts


def run_segment(
    scans: list[LidarScan],
    warmup: list[LidarScan],
    options,  # noqa: ANN001 - CtLidarOptions
    world_frame: str,
    progress: bool = False,
    leadout: Seq[LidarScan] = (),
) -> Trajectory:
    """The odometry over ``warmup + scans`` (:func:`run_segment_passes`' first trajectory)."""
    return run_segment_passes(scans, warmup, options, world_frame, progress, leadout)[0]


def run_segment_passes(
    scans: list[LidarScan],
    warmup: list[LidarScan],
    options,  # noqa: ANN001 - CtLidarOptions
    world_frame: str,
    progress: bool = False,
    leadout: Seq[LidarScan] = (),
) -> tuple[Trajectory, Trajectory | None]:
    """The odometry over ``warmup + scans``; keeps the poses from the segment's first point.

    A start mid-swing can lose track within a few seconds, and so can a hard swing met with a
    young map (measured: of 12 four-second hand-held OS1-16 segments with a 1 s warm-up, 4 of
    the first 9 lost, while the whole 20 s run from rest tracks to 0.2 cm). So where track is
    lost before ``cold_start_window_s`` into the segment, the odometry starts again twice as
    far back (:func:`cold_starts`), up to ``cold_starts`` starts; a later loss, or the last
    start's, is raised.

    With ``options.backward_pass is True`` the poses are averaged with a backward pass over
    ``warmup + scans + leadout`` (:mod:`l2calib.references.ct_smoothing`; ``leadout``: scans
    after the segment, where that pass starts).

    Returns:
        The poses ``T_world_lidar`` and, with a backward pass that tracked, the forward pass
        alone at the same stamps (:attr:`ReferenceTrajectory.alternative`); else ``None``.

    Raises:
        ReferenceSourceError: fewer than 2 scans, or a non-finite pose.
        ReferenceLostTrackError: every start lost track.
    """
    starts = cold_starts(warmup, scans[0].stamp_ns, options)
    for n, i in enumerate(starts):
        all_scans = warmup[i:] + scans
        odo = CtLidarOdometry(options)
        try:
            stamps, motions = _run(odo, all_scans, world_frame, progress)
            break
        except ReferenceLostTrackError as exc:
            back = (scans[0].stamp_ns - all_scans[0].stamp_ns) / NS_PER_S
            early = (
                odo.lost_at_s is not None and odo.lost_at_s - back <= options.cold_start_window_s
            )
            if n == len(starts) - 1 or not early:
                if n == 0:
                    raise
                raise ReferenceLostTrackError(
                    f"{exc.message} (start {n + 1} of {len(starts)}, {back:.1f} s before "
                    f"{world_frame}; the starts nearer to it lost track too)",
                    fix=exc.fix,
                ) from exc
            log.info("%s: lost track %.1f s after start %d; starting earlier", world_frame,
                     odo.lost_at_s, n + 1)  # fmt: skip
    t, R, p = sample_poses(stamps, motions, all_scans[-1].end_stamp_ns, options.poses_per_scan)
    keep = t >= scans[0].stamp_ns
    if options.backward_pass is not True:
        return _poses(t, R, p, keep, world_frame), None
    Rs, ps, fwd = _both_passes(t, R, p, all_scans + list(leadout), options, world_frame, progress)
    forward = None if fwd is None else _poses(t, *fwd, keep, world_frame)
    return _poses(t, Rs, ps, keep, world_frame), forward


def _poses(t, R, p, keep: np.ndarray, world_frame: str) -> Trajectory:  # noqa: ANN001
    """The trajectory of the poses ``keep`` selects."""
    q = Rotation.from_matrix(R[keep]).as_quat()
    return Trajectory(t[keep].astype(np.int64), p[keep], q, "lidar", world_frame)


def _both_passes(t, R, p, scans, options, world_frame: str, progress: bool):  # noqa: ANN001, ANN202
    """Forward poses ``t, R, p`` averaged with a backward pass over ``scans`` (ct_smoothing).

    Returns:
        The averaged ``R``, ``p`` and the forward ``(R, p)`` — the reference's alternative —
        or ``None`` in its place when the backward pass lost track (the forward poses are then
        returned as they are: one estimate only).
    """
    from l2calib.references.ct_smoothing import smoothed

    def run(rev: list[LidarScan]):  # noqa: ANN202
        return _run(CtLidarOdometry(options), rev, f"{world_frame} (backward)", progress)

    Rs, ps = smoothed(t, R, p, scans, options, run, world_frame)
    return Rs, ps, (None if Rs is R else (R, p))  # smoothed hands R back when it did not fuse


def _run(odo: CtLidarOdometry, scans: list[LidarScan], world_frame: str, progress: bool):  # noqa: ANN202
    """``odo.run(scans)``, with a progress bar when asked."""
    if not progress:
        return odo.run(scans)
    from rich.progress import Progress

    with Progress(transient=True) as bar:
        task = bar.add_task(f"{NAME} {world_frame}", total=len(scans) - 1)
        return odo.run(scans, on_scan=lambda _: bar.advance(task))


class CtLidarReference(LidarOdometryReference):
    """Reference trajectories from the continuous-time LiDAR odometry, cached on disk.

    Args:
        options: :class:`~l2calib.references.options.CtLidarOptions`.
        sequences: The sequences the segments were cut from, for warm-up scans (or ``None``).
        progress: Show a progress bar per segment.
    """

    name = NAME

    def __init__(self, options, sequences=None, progress: bool = False, **context) -> None:  # noqa: ANN001
        """Resolves ``auto`` options with ``context["planar_motion"]``.

        The pipeline's IMU check: on planar, yaw-dominant motion the backward pass and the
        vehicle prior (:data:`~l2calib.references.options.VEHICLE_MOTION_NOISE`); resolved
        here so that the cache key holds what ran (the general values key as before).
        """
        self.notes: list[str] = []
        planar = bool(context.get("planar_motion", False))
        if options.backward_pass == "auto":
            options = options.model_copy(update={"backward_pass": planar})
            if planar:
                self.notes.append(
                    "planar, yaw-dominant motion and reference.options.backward_pass: auto: "
                    "ct-lidar also runs backwards in time and averages the two passes "
                    "(experimental; twice the reference's time)"
                )
        if "auto" in (options.noise_rot_deg, options.noise_rate_rad_s):
            rot, rate = options.motion_noise(planar)
            options = options.model_copy(update={"noise_rot_deg": rot, "noise_rate_rad_s": rate})
            if planar:
                self.notes.append(
                    f"planar, yaw-dominant motion: ct-lidar's vehicle prior (attitude noise "
                    f"{rot:g} deg/sqrt(s), body rate {rate:g} rad/s/sqrt(s); "
                    "reference.options.noise_rot_deg / noise_rate_rad_s)"
                )
        super().__init__(options, sequences, progress, **context)

    def key_options(self) -> dict[str, Any]:
        """The options that decide the result; without the backward pass, keys as before it."""
        opts = super().key_options()
        if opts.get("backward_pass") is False:
            del opts["backward_pass"]
        elif opts.get("backward_pass") is True:  # entries since the forward pass is kept too
            opts["alternative"] = "forward pass"
        return opts

    def version(self) -> str:
        """Version of the engine's results."""
        return ENGINE_VERSION

    def warmup_s(self) -> float:
        """``margin_s`` times room for the earlier starts (:func:`cold_starts`)."""
        return self.options.margin_s * 2 ** (self.options.cold_starts - 1)

    def run_segment(
        self,
        scans: list[LidarScan],
        warmup: list[LidarScan],
        world_frame: str,
        leadout: Seq[LidarScan] = (),
    ) -> Trajectory:
        """The odometry over the segment (see :func:`run_segment`)."""
        return run_segment(scans, warmup, self.options, world_frame, self.progress, leadout)

    def run_passes(
        self,
        scans: list[LidarScan],
        warmup: list[LidarScan],
        world_frame: str,
        leadout: Seq[LidarScan] = (),
    ) -> tuple[Trajectory, Trajectory | None]:
        """The odometry over the segment and its forward pass alone (:func:`run_segment_passes`)."""
        return run_segment_passes(scans, warmup, self.options, world_frame, self.progress, leadout)

    def leadout(self, seg: Segment) -> list[LidarScan]:
        """``backward_leadout_s`` of scans after the segment, where the backward pass starts."""
        seq = self.sequences.get(seg.sequence)
        if self.options.backward_pass is not True or seq is None or not seg.measurements:
            return []
        return self._after(seq, seg.scans[-1].stamp_ns)

    def _after(self, seq, last_ns: int) -> list[LidarScan]:  # noqa: ANN001
        """The sequence's scans within ``backward_leadout_s`` after the scan at ``last_ns``."""
        end = last_ns + int(self.options.backward_leadout_s * NS_PER_S)
        return [m for m in seq.scans.load(last_ns + 1, end) if isinstance(m, LidarScan)]

    def compute_results(
        self, segments: Seq[Segment]
    ) -> dict[str, ReferenceTrajectory | ReferenceLostTrackError]:
        """Segments cut from shared runs (:mod:`~l2calib.references.ct_runs`), else one by one."""
        o = self.options
        runs, alone = plan_runs(segments, self.sequences, o.from_start_s, o.chain_gap_s, o.margin_s)
        out = super().compute_results(alone)
        for run in runs:
            if len(run.segments) == 1 and not run.leads_in():  # the per-segment path's own run
                out |= super().compute_results(run.segments)
                continue
            try:
                out |= self._compute_run(run)
            except ReferenceLostTrackError as exc:
                names = ", ".join(s.name for s in run.segments)
                log.info("%s: the run over %s lost track (%s); each segment on its own",
                         self.name, names, exc.message)  # fmt: skip
                out |= super().compute_results(run.segments)
        return out

    def _compute_run(self, run: OdometryRun) -> dict[str, ReferenceTrajectory]:
        """One odometry over the run, cut into its segments (each cached on its own)."""
        scans = run.scans()
        opts = self.key_options()
        run_id = segment_fingerprint(scans, run.start_ns, scans[-1].stamp_ns)
        leadout = (
            self._after(run.sequence, scans[-1].stamp_ns)
            if self.options.backward_pass is True
            else []
        )
        if leadout:
            run_id = {**run_id, "leadout": segment_fingerprint(leadout, 0, 0)}
        keys = {
            s.name: cache_key(
                {
                    "source": self.name,
                    "engine": self.version(),
                    "options": opts,
                    "run": run_id,
                    "segment": segment_fingerprint(s.scans, s.start_ns, s.end_ns),
                }
            )
            for s in run.segments
        }
        hits = {n: self.cache.load(k) for n, k in keys.items()} if self.cache.enabled else {}
        cached = bool(hits) and all(a is not None for a in hits.values())
        # one world frame for the segments of one run: the LIO backend's shared map spans a frame
        frame = f"{self.name}:{run.sequence.name}@{run.start_ns}"
        if cached:
            arrays = hits
        else:
            world = f"{self.name}:{run.sequence.name} run"
            stamps, motions = _run(CtLidarOdometry(self.options), scans, world, self.progress)
            t, R, p = sample_poses(
                stamps, motions, scans[-1].end_stamp_ns, self.options.poses_per_scan
            )
            forward = None
            if self.options.backward_pass is True:
                R, p, forward = _both_passes(
                    t, R, p, scans + leadout, self.options, world, self.progress
                )
            arrays = {
                s.name: trajectory_arrays(
                    cut(t, R, p, s, frame), None if forward is None else cut(t, *forward, s, frame)
                )
                for s in run.segments
            }
            for s in run.segments if self.cache.enabled else []:
                summary = {"source": self.name, "segment": s.name, "run_scans": len(scans)}
                try:
                    self.cache.store(keys[s.name], arrays[s.name], summary)
                except OSError as exc:  # as ReferenceCache.get_or_compute: never stops a run
                    log.warning("cannot write the reference cache (%s)", exc)
        trajs = {n: trajectory_from_arrays(a, "lidar", frame) for n, a in arrays.items()}
        lead = (run.segments[0].scans[0].stamp_ns - run.start_ns) / NS_PER_S
        log.info("%s: %d segment(s) of %s from one run starting %.1f s before the first (%s)",
                 self.name, len(trajs), run.sequence.name, lead,
                 "cached" if cached else "computed")  # fmt: skip
        alternatives = {n: alternative_from_arrays(a, "lidar", frame) for n, a in arrays.items()}
        return {
            n: ReferenceTrajectory(n, tr, "pose", self.name, alternative=alternatives[n])
            for n, tr in trajs.items()
        }
