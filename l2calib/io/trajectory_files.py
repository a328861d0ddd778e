"""Trajectory files: TUM, KITTI (+ times file) and CSV.

* **TUM**: ``timestamp tx ty tz qx qy qz qw`` per line, timestamp in seconds, ``#`` comments.
* **KITTI**: 12 numbers per line, the row-major top 3×4 of ``T_world_body``; stamps come from a
  separate times file (one time in seconds per line, as in KITTI's ``times.txt``).
* **CSV**: a header naming the columns. Accepted headers: ``stamp_ns,x,y,z,qx,qy,qz,qw``;
  ``timestamp_s,x,y,z,qx,qy,qz,qw``; and EuRoC ground truth
  (``#timestamp [ns], p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], ...``).

Seconds are parsed as decimal text, so stamps keep full nanosecond precision.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
import torch

from l2calib import geometry as geo
from l2calib.errors import DataError, FormatError
from l2calib.trajectory import NS_PER_S, Trajectory

TUM_COLUMNS = "timestamp tx ty tz qx qy qz qw"
KITTI_COLUMNS = "r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz"
CSV_COLUMNS = "stamp_ns,x,y,z,qx,qy,qz,qw"
TrajectoryFormat = Literal["tum", "kitti", "csv"]


def parse_seconds_ns(text: str) -> int:
    """Parses a decimal seconds string (``"1403636580.838555648"``) to exact int nanoseconds.

    Raises:
        ValueError: if ``text`` is not a plain decimal number.
    """
    text = text.strip()
    if "e" in text.lower():
        return int(round(float(text) * NS_PER_S))
    sign = -1 if text.startswith("-") else 1
    body = text.lstrip("+-")
    whole, _, frac = body.partition(".")
    if (
        not (whole or frac)
        or not (whole.isdigit() or whole == "")
        or not (frac.isdigit() or frac == "")
    ):
        raise ValueError(f"not a number: {text!r}")
    frac = (frac + "000000000")[:9]
    return sign * (int(whole or "0") * NS_PER_S + int(frac))


def format_seconds(stamp_ns: int) -> str:
    """Formats int nanoseconds as exact decimal seconds (``"12.000000001"``)."""
    sign = "-" if stamp_ns < 0 else ""
    s, ns = divmod(abs(int(stamp_ns)), NS_PER_S)
    return f"{sign}{s}.{ns:09d}"


def _rows(path: Path) -> list[tuple[int, list[str]]]:
    if not path.is_file():
        raise DataError(f"{path}: no such file", fix="check the path")
    out = []
    with path.open() as fh:
        for lineno, line in enumerate(fh, start=1):
            stripped = line.strip()
            if not stripped or stripped.startswith("#"):
                continue
            out.append((lineno, stripped.replace(",", " ").split()))
    if not out:
        raise FormatError(f"{path}: the file holds no poses")
    return out


def _floats(path: Path, lineno: int, fields: list[str], expected: str) -> list[float]:
    try:
        vals = [float(f) for f in fields]
    except ValueError:
        raise FormatError(
            f"{path}:{lineno}: non-numeric value in {' '.join(fields)!r}; expected columns "
            f"'{expected}'"
        ) from None
    if not np.all(np.isfinite(vals)):
        raise FormatError(f"{path}:{lineno}: NaN or infinite value; expected columns '{expected}'")
    return vals


def _check_count(path: Path, lineno: int, fields: list[str], n: int, expected: str) -> None:
    if len(fields) != n:
        raise FormatError(
            f"{path}:{lineno}: {len(fields)} columns, expected {n} ('{expected}')",
            fix="check the file format (tum, kitti or csv) and its column order",
        )


def _stamp(path: Path, lineno: int, text: str, what: str) -> int:
    try:
        return parse_seconds_ns(text)
    except ValueError:
        raise FormatError(f"{path}:{lineno}: {what} {text!r} is not a number") from None


def _build(path: Path, stamps, pos, quat, body_frame: str) -> Trajectory:
    stamps = np.asarray(stamps, dtype=np.int64)
    order_ok = np.all(np.diff(stamps) > 0)
    if not order_ok:
        bad = int(np.argmax(np.diff(stamps) <= 0))
        raise FormatError(
            f"{path}: stamps are not strictly increasing at pose {bad + 2}",
            fix="sort the file by time and remove duplicate stamps",
        )
    quat = np.asarray(quat, dtype=np.float64)
    norms = np.linalg.norm(quat, axis=1)
    if np.any(np.abs(norms - 1) > 1e-3):
        bad = int(np.argmax(np.abs(norms - 1)))
        raise FormatError(
            f"{path}: quaternion of pose {bad + 1} has norm {norms[bad]:.4f}",
            fix="write unit quaternions in the order qx qy qz qw",
        )
    return Trajectory(stamps, np.asarray(pos, dtype=np.float64), quat, body_frame)


# --------------------------------------------------------------------------- TUM
def read_tum(path: str | Path, body_frame: str = "body") -> Trajectory:
    """Reads a TUM file (``timestamp tx ty tz qx qy qz qw``, seconds)."""
    path = Path(path)
    stamps, pos, quat = [], [], []
    for lineno, f in _rows(path):
        _check_count(path, lineno, f, 8, TUM_COLUMNS)
        stamps.append(_stamp(path, lineno, f[0], "timestamp"))
        v = _floats(path, lineno, f[1:], TUM_COLUMNS)
        pos.append(v[:3])
        quat.append(v[3:])
    return _build(path, stamps, pos, quat, body_frame)


def write_tum(path: str | Path, traj: Trajectory) -> None:
    """Writes ``traj`` as a TUM file with exact nanosecond stamps."""
    lines = [f"# {TUM_COLUMNS}  (T_{traj.world_frame}_{traj.body_frame}, seconds, meters)"]
    for s, p, q in zip(traj.stamps_ns, traj.t_world_body, traj.quat_xyzw, strict=True):
        vals = " ".join(f"{v:.9f}" for v in (*p, *q))
        lines.append(f"{format_seconds(int(s))} {vals}")
    Path(path).write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- KITTI
def read_kitti(
    path: str | Path, times_path: str | Path | None, body_frame: str = "body"
) -> Trajectory:
    """Reads KITTI poses (3×4 row-major per line) with stamps from ``times_path`` (seconds)."""
    path = Path(path)
    if times_path is None:
        raise FormatError(
            f"{path}: KITTI poses carry no time stamps",
            fix="give the times file (one time in seconds per line), e.g. times.txt",
        )
    times_path = Path(times_path)
    mats = []
    for lineno, f in _rows(path):
        _check_count(path, lineno, f, 12, KITTI_COLUMNS)
        mats.append(_floats(path, lineno, f, KITTI_COLUMNS))
    stamps = []
    for lineno, f in _rows(times_path):
        _check_count(times_path, lineno, f, 1, "time in seconds")
        stamps.append(_stamp(times_path, lineno, f[0], "time"))
    if len(stamps) != len(mats):
        raise FormatError(
            f"{path} has {len(mats)} poses but {times_path} has {len(stamps)} times",
            fix="use the times file that belongs to these poses",
        )
    T = np.tile(np.eye(4), (len(mats), 1, 1))
    T[:, :3, :4] = np.asarray(mats).reshape(-1, 3, 4)
    R = torch.from_numpy(T[:, :3, :3])
    ortho = (R.transpose(1, 2) @ R - torch.eye(3, dtype=R.dtype)).abs().amax(dim=(1, 2))
    if torch.any(ortho > 1e-3):
        bad = int(torch.argmax(ortho))
        raise FormatError(
            f"{path}: pose {bad + 1} has a non-orthonormal rotation "
            f"(error {float(ortho[bad]):.3g})",
            fix=f"write each line as '{KITTI_COLUMNS}'",
        )
    quat = geo.matrix_to_quat(R).numpy()
    return _build(path, stamps, T[:, :3, 3], quat, body_frame)


def write_kitti(path: str | Path, traj: Trajectory, times_path: str | Path | None = None) -> None:
    """Writes KITTI poses (and, if given, the times file in seconds)."""
    T = traj.matrices().numpy()
    lines = [" ".join(f"{v:.9e}" for v in m[:3, :4].reshape(-1)) for m in T]
    Path(path).write_text("\n".join(lines) + "\n")
    if times_path is not None:
        Path(times_path).write_text(
            "\n".join(format_seconds(int(s)) for s in traj.stamps_ns) + "\n"
        )


# --------------------------------------------------------------------------- CSV
_EUROC_PREFIX = ("#timestamp", "p_rs_r_x", "p_rs_r_y", "p_rs_r_z", "q_rs_w", "q_rs_x", "q_rs_y")


def _csv_layout(path: Path, header: str) -> tuple[str, list[int]]:
    """Returns (stamp kind, column indices of x y z qx qy qz qw) for a CSV header."""
    names = [h.strip().lower().split(" [")[0].split("[")[0].strip() for h in header.split(",")]
    if names[:7] == list(_EUROC_PREFIX):
        return "ns", [1, 2, 3, 5, 6, 7, 4]
    want = ["x", "y", "z", "qx", "qy", "qz", "qw"]
    for stamp_col, kind in (("stamp_ns", "ns"), ("timestamp_s", "s")):
        if stamp_col in names and all(w in names for w in want):
            return kind, [names.index(stamp_col)] + [names.index(w) for w in want]
    raise FormatError(
        f"{path}:1: unrecognised CSV header {header.strip()!r}",
        fix=f"use the header '{CSV_COLUMNS}' (or timestamp_s instead of stamp_ns, or EuRoC's)",
    )


def read_csv(path: str | Path, body_frame: str = "body") -> Trajectory:
    """Reads a CSV trajectory with a header (see module docstring for accepted headers)."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file", fix="check the path")
    with path.open() as fh:
        header = fh.readline()
    kind, cols = _csv_layout(path, header)
    if len(cols) == 7:  # EuRoC: stamp in column 0
        cols = [0] + cols
    stamps, pos, quat = [], [], []
    ncol = len(header.split(","))
    expected = header.strip()
    for lineno, f in _rows(path):
        if lineno == 1:
            continue
        _check_count(path, lineno, f, ncol, expected)
        try:
            stamp = int(f[cols[0]]) if kind == "ns" else parse_seconds_ns(f[cols[0]])
        except ValueError:
            raise FormatError(
                f"{path}:{lineno}: stamp {f[cols[0]]!r} is not an integer number of "
                f"{'nanoseconds' if kind == 'ns' else 'seconds'}"
            ) from None
        v = _floats(path, lineno, [f[c] for c in cols[1:]], expected)
        stamps.append(stamp)
        pos.append(v[:3])
        quat.append(v[3:])
    return _build(path, stamps, pos, quat, body_frame)


def write_csv(path: str | Path, traj: Trajectory) -> None:
    """Writes ``traj`` as CSV with header ``stamp_ns,x,y,z,qx,qy,qz,qw``."""
    lines = [CSV_COLUMNS]
    for s, p, q in zip(traj.stamps_ns, traj.t_world_body, traj.quat_xyzw, strict=True):
        lines.append(f"{int(s)}," + ",".join(f"{v:.9f}" for v in (*p, *q)))
    Path(path).write_text("\n".join(lines) + "\n")


# --------------------------------------------------------------------------- dispatch
def guess_format(path: str | Path) -> TrajectoryFormat:
    """Guesses the format from the extension (.tum/.txt -> tum, .csv -> csv, .kitti -> kitti)."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return "csv"
    if suffix == ".kitti":
        return "kitti"
    if suffix in (".tum", ".txt"):
        return "tum"
    raise FormatError(
        f"{path}: cannot tell the trajectory format from the extension {suffix!r}",
        fix="name the format explicitly: tum, kitti or csv",
    )


def read_trajectory(
    path: str | Path,
    fmt: TrajectoryFormat | None = None,
    times_path: str | Path | None = None,
    body_frame: str = "body",
) -> Trajectory:
    """Reads a trajectory file in ``fmt`` (guessed from the extension if ``None``)."""
    fmt = fmt or guess_format(path)
    if fmt == "tum":
        return read_tum(path, body_frame)
    if fmt == "csv":
        return read_csv(path, body_frame)
    if fmt == "kitti":
        return read_kitti(path, times_path, body_frame)
    raise FormatError(f"unknown trajectory format {fmt!r}", fix="use tum, kitti or csv")


def write_trajectory(
    path: str | Path,
    traj: Trajectory,
    fmt: TrajectoryFormat | None = None,
    times_path: str | Path | None = None,
) -> None:
    """Writes ``traj`` in ``fmt`` (guessed from the extension if ``None``)."""
    fmt = fmt or guess_format(path)
    if fmt == "tum":
        write_tum(path, traj)
    elif fmt == "csv":
        write_csv(path, traj)
    elif fmt == "kitti":
        write_kitti(path, traj, times_path)
    else:
        raise FormatError(f"unknown trajectory format {fmt!r}", fix="use tum, kitti or csv")
