"""``ct-lidar``'s backward pass: the odometry run again backwards in time, the two averaged.

EXPERIMENTAL (``reference.options.backward_pass``; the default ``auto`` runs it for ground
vehicles). The odometry is a filter: each scan is solved against a map of the scans before it,
with a motion prior from them, so its error depends on the way it came. Run backwards in time
(the scans in reverse order, each scan's point times mirrored) the same odometry makes a
different error; the average of the two passes keeps what they agree on. Where the forward error
follows the turns that carry the horizontal lever arm's signal (a 1 cm lateral lever arm tilts a
LIO's attitude by about 0.015° in a 0.5 rad/s turn), that is what moves a LiDAR-only calibration
of a ground vehicle.

Measured on the simulator's 60 s drive (``ugv drive ouster-os1-16 ct-lidar``, the 30 s the
selection keeps; ``python -m benchmarks.experiment_reference_error``): the reward's peak along
the IMU's y is +2.21 to +2.71 cm from the truth with the forward pass alone (three sampling
seeds: a systematic error), and +0.69, +1.31, +2.22 and +1.22 cm with the two passes averaged,
as the backward pass started 1 s after each segment, at the run's end, 1 s or 5 s after it
(``backward_leadout_s``); on the VLP-16 drive +4.16 forward, +3.55 / +2.40 / +2.89 averaged.
Better every time, by an amount that depends on where the backward pass starts (cold, while
driving); ``docs/references.md``, "Backward pass".

Both passes use the LiDAR alone; the backward pass costs a second run.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from l2calib.data import NS_PER_S, LidarScan
from l2calib.errors import ReferenceLostTrackError
from l2calib.references.ct_motion import sample_poses
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")

#: Weight (m²) of one pose's orientation (chordal, ``|R_f − A R_b|²``) against its position
#: (``|p_f − A p_b − s|²``) in the fit of the backward frame onto the forward one.
ORIENTATION_WEIGHT_M2 = 1.0
#: One odometry run: scans in time order -> (scan start stamps [S] ns, per-scan motions).
Run = Callable[[list[LidarScan]], tuple[np.ndarray, list[Any]]]


def reversed_scans(scans: list[LidarScan]) -> tuple[list[LidarScan], int]:
    """The scans backwards in time: order reversed, each scan's point times mirrored.

    Time ``t`` maps to ``t0 - t`` with ``t0`` = the first scan's start + the last scan's end,
    so the reversed scans span the same interval.

    Args:
        scans: LiDAR scans in time order.

    Returns:
        The reversed scans (in their own time order) and ``t0`` (ns).
    """
    t0 = int(scans[0].stamp_ns + scans[-1].end_stamp_ns)
    out = []
    for s in reversed(scans):
        offsets = np.asarray(s.offset_s, np.float64)
        mirrored = (s.end_stamp_ns - s.stamp_ns) / NS_PER_S - offsets
        order = np.argsort(mirrored, kind="stable")
        out.append(
            LidarScan(
                stamp_ns=t0 - s.end_stamp_ns,
                points_lidar=np.asarray(s.points_lidar)[order],
                offset_s=np.clip(mirrored[order], 0.0, None).astype(np.asarray(s.offset_s).dtype),
                intensity=None if s.intensity is None else np.asarray(s.intensity)[order],
                ring=None if s.ring is None else np.asarray(s.ring)[order],
            )
        )
    return out, t0


def backward_poses(scans: list[LidarScan], options: Any, run: Run) -> tuple[np.ndarray, ...]:
    """The odometry over ``scans`` backwards in time, its poses in forward time order.

    Args:
        scans: LiDAR scans in time order.
        options: :class:`~l2calib.references.options.CtLidarOptions`.
        run: ``run(scans) -> (stamps_ns, motions)``: one odometry run (the caller's, so that it
            can show progress).

    Returns:
        Stamps ``[N]`` int64 ns (ascending), rotations ``[N, 3, 3]`` and positions ``[N, 3]``
        of ``T_world_lidar`` in the backward run's own world frame.
    """
    rev, t0 = reversed_scans(scans)
    stamps, motions = run(rev)
    t, R, p = sample_poses(stamps, motions, rev[-1].end_stamp_ns, options.poses_per_scan)
    t_fwd = t0 - t.astype(np.int64)
    order = np.argsort(t_fwd, kind="stable")
    return t_fwd[order], R[order], p[order]


def fuse(
    t_ns: np.ndarray, R: np.ndarray, p: np.ndarray, back: tuple[np.ndarray, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """The average of the forward poses and the backward ones brought into their frame.

    The backward run's world frame is mapped onto the forward one by the rigid motion that
    best carries its positions and orientations onto the forward ones (one Procrustes fit of
    both, orientations weighted by :data:`ORIENTATION_WEIGHT_M2`: over a drive the positions
    decide, and on a straight one, where positions leave the roll about the path free, the
    orientations do). Each pose is then the midpoint of the two: positions averaged, rotations
    halfway along the geodesic. Forward poses outside the backward run's span stay as they are.

    Args:
        t_ns: ``[N]`` forward stamps (ns, ascending).
        R: ``[N, 3, 3]`` forward rotations.
        p: ``[N, 3]`` forward positions.
        back: ``(t_ns, R, p)`` of :func:`backward_poses`.

    Returns:
        Rotations ``[N, 3, 3]`` and positions ``[N, 3]`` at ``t_ns``.
    """
    tb, Rb, pb = back
    inside = (t_ns >= tb[0]) & (t_ns <= tb[-1])
    if inside.sum() < 2:
        return R, p
    # drop repeated stamps (a scan's end is the next one's start) for the interpolation
    tb, keep = np.unique(tb, return_index=True)
    quat = Rotation.from_matrix(Rb[keep]).as_quat()
    b = Trajectory(tb, pb[keep], quat, "lidar", "backward").interpolate(t_ns[inside])
    Rb_i, pb_i = Rotation.from_quat(b.quat_xyzw), b.t_world_body
    Rf = Rotation.from_matrix(R[inside])
    pf = p[inside]
    # Procrustes on positions and orientations together: max tr(Aᵀ M) over rotations A
    dpf, dpb = pf - pf.mean(0), pb_i - pb_i.mean(0)
    M = dpf.T @ dpb + ORIENTATION_WEIGHT_M2 * (Rf * Rb_i.inv()).as_matrix().sum(0)
    U, _, Vt = np.linalg.svd(M)
    A = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    pb_w = pb_i @ A.T
    shift = (pf - pb_w).mean(0)
    Rb_w = Rotation.from_matrix(A) * Rb_i
    R_out, p_out = R.copy(), p.copy()
    R_out[inside] = (Rf * Rotation.from_rotvec(0.5 * (Rf.inv() * Rb_w).as_rotvec())).as_matrix()
    p_out[inside] = 0.5 * (p[inside] + pb_w + shift)
    return R_out, p_out


def smoothed(
    t_ns: np.ndarray,
    R: np.ndarray,
    p: np.ndarray,
    scans: list[LidarScan],
    options: Any,
    run: Run,
    where: str,
) -> tuple[np.ndarray, np.ndarray]:
    """Forward poses averaged with a backward pass over ``scans``, or as they are if it fails.

    A backward pass that loses track (it starts cold at the end of the scans, where the
    forward pass had a warm-up) leaves the forward poses unchanged — the same ``R``, ``p``
    objects come back, which tells the caller there is no second estimate — with a warning
    naming ``where``.
    """
    try:
        back = backward_poses(scans, options, run)
    except ReferenceLostTrackError as exc:
        log.warning(
            "ct-lidar's backward pass lost track on %s (%s): the forward pass alone is used",
            where,
            exc.message,
        )
        return R, p
    return fuse(t_ns, R, p, back)
