"""On-disk cache of computed references (and of other arrays that are slow to recompute).

An entry is keyed by a SHA-256 over a canonical JSON of everything the result depends on: the
source's name and options, a fingerprint of the input data (:func:`segment_fingerprint` hashes
the scans' stamps and points; :func:`file_fingerprint` a file's size, mtime and path) and a format
version. A changed input or setting gives another key, so stale entries are never read.

Layout: ``<root>/<key[:2]>/<key>.npz`` (the arrays) and ``<key>.json`` (a header with the
npz's SHA-256, shapes, dtypes and a readable summary). The npz is written first and the header
last, both through a temporary file and an atomic rename, so a crash leaves no half entry that
looks complete. A corrupted entry (unreadable header, checksum mismatch, missing arrays) is
reported as a warning, deleted and recomputed.

The root is ``cache_dir`` if given, else ``$L2CALIB_CACHE/references``, else
``$XDG_CACHE_HOME/l2calib/references`` (``~/.cache/l2calib/references``).
"""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from l2calib.data import LidarScan
from l2calib.trajectory import Trajectory

log = logging.getLogger("l2calib.references")
FORMAT_VERSION = 1
ENV_VAR = "L2CALIB_CACHE"


def default_root() -> Path:
    """The cache root when no ``cache_dir`` is configured (see module docstring)."""
    if os.environ.get(ENV_VAR):
        return Path(os.environ[ENV_VAR]).expanduser() / "references"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base).expanduser() / "l2calib" / "references"


def cache_key(payload: dict[str, Any]) -> str:
    """SHA-256 hex digest of a JSON-serialisable payload (keys sorted)."""
    text = json.dumps({"format": FORMAT_VERSION, **payload}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def scans_fingerprint(scans: Iterable[LidarScan]) -> str:
    """BLAKE2b of every scan's stamp, point count, points and per-point times (content hash)."""
    h = hashlib.blake2b(digest_size=20)
    for s in scans:
        h.update(np.int64(s.stamp_ns).tobytes())
        h.update(np.int64(len(s)).tobytes())
        h.update(np.ascontiguousarray(s.points_lidar, dtype=np.float32).data)
        h.update(np.ascontiguousarray(s.offset_s, dtype=np.float32).data)
    return h.hexdigest()


def segment_fingerprint(scans: list[LidarScan], start_ns: int, end_ns: int) -> dict[str, Any]:
    """Identity of a segment's LiDAR data: window, scan count and a content hash."""
    return {
        "start_ns": int(start_ns),
        "end_ns": int(end_ns),
        "scans": len(scans),
        "content": scans_fingerprint(scans),
    }


def file_fingerprint(path: str | Path) -> dict[str, Any]:
    """Identity of a file or bag directory: resolved path, total size and newest mtime."""
    p = Path(path).resolve()
    files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
    stats = [q.stat() for q in files]
    return {
        "path": str(p),
        "size": sum(s.st_size for s in stats),
        "mtime_ns": max((s.st_mtime_ns for s in stats), default=0),
    }


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


class ReferenceCache:
    """A directory of cached array bundles.

    Args:
        root: Cache directory (default: :func:`default_root`).
        enabled: If false, :meth:`get_or_compute` always computes and nothing is written.
    """

    def __init__(self, root: str | Path | None = None, enabled: bool = True) -> None:
        self.root = Path(root).expanduser() if root else default_root()
        self.enabled = enabled

    def paths(self, key: str) -> tuple[Path, Path]:
        """``(arrays.npz, header.json)`` of an entry."""
        d = self.root / key[:2]
        return d / f"{key}.npz", d / f"{key}.json"

    def load(self, key: str) -> dict[str, np.ndarray] | None:
        """The arrays of an entry, or ``None`` if absent.

        A corrupted entry is reported as a warning, deleted, and ``None`` is returned.
        """
        npz, header = self.paths(key)
        if not header.exists():
            return None
        try:
            head = json.loads(header.read_text())
            blob = npz.read_bytes()
            if hashlib.sha256(blob).hexdigest() != head["sha256"]:
                raise ValueError("checksum mismatch (truncated or modified file)")
            with np.load(io.BytesIO(blob), allow_pickle=False) as data:
                arrays = {name: data[name] for name in data.files}
            for name, (shape, dtype) in head["arrays"].items():
                a = arrays[name]
                if list(a.shape) != list(shape) or str(a.dtype) != dtype:
                    raise ValueError(f"array {name!r} is {a.dtype}{list(a.shape)}")
        except Exception as exc:  # any failure to read back means the entry is unusable
            log.warning(
                "reference cache entry %s is corrupted (%s: %s); deleting it and recomputing",
                header.with_suffix(""),
                type(exc).__name__,
                exc,
            )
            self.delete(key)
            return None
        return arrays

    def store(self, key: str, arrays: dict[str, np.ndarray], summary: dict[str, Any]) -> None:
        """Writes an entry (arrays first, header last; atomic renames)."""
        npz, header = self.paths(key)
        npz.parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        blob = buf.getvalue()
        _atomic_write(npz, blob)
        head = {
            "format": FORMAT_VERSION,
            "sha256": hashlib.sha256(blob).hexdigest(),
            "arrays": {k: [list(v.shape), str(v.dtype)] for k, v in arrays.items()},
            "summary": summary,
        }
        _atomic_write(header, (json.dumps(head, indent=1, default=str) + "\n").encode())

    def delete(self, key: str) -> None:
        """Removes an entry (no error if absent)."""
        for p in self.paths(key):
            p.unlink(missing_ok=True)

    def get_or_compute(
        self,
        key: str,
        compute: Callable[[], dict[str, np.ndarray]],
        summary: dict[str, Any] | None = None,
    ) -> tuple[dict[str, np.ndarray], bool]:
        """Cached arrays of ``key``, or ``compute()`` stored under it.

        Returns:
            The arrays and whether they came from the cache.
        """
        if self.enabled:
            hit = self.load(key)
            if hit is not None:
                return hit, True
        arrays = compute()
        if self.enabled:
            try:
                self.store(key, arrays, summary or {})
            except OSError as exc:  # a read-only or full disk must not stop a calibration
                log.warning("cannot write the reference cache in %s (%s)", self.root, exc)
        return arrays, False


def trajectory_arrays(
    traj: Trajectory, alternative: Trajectory | None = None
) -> dict[str, np.ndarray]:
    """A trajectory as cacheable arrays, with an alternative estimate at the same stamps."""
    out = {
        "stamps_ns": traj.stamps_ns,
        "t_world_body": traj.t_world_body,
        "quat_xyzw": traj.quat_xyzw,
    }
    if alternative is not None:
        out |= {
            "alternative_t_world_body": alternative.t_world_body,
            "alternative_quat_xyzw": alternative.quat_xyzw,
        }
    return out


def trajectory_from_arrays(
    arrays: dict[str, np.ndarray], body_frame: str, world_frame: str
) -> Trajectory:
    """Inverse of :func:`trajectory_arrays` (validated by :class:`Trajectory`)."""
    return Trajectory(
        arrays["stamps_ns"], arrays["t_world_body"], arrays["quat_xyzw"], body_frame, world_frame
    )


def alternative_from_arrays(
    arrays: dict[str, np.ndarray], body_frame: str, world_frame: str
) -> Trajectory | None:
    """The alternative estimate stored by :func:`trajectory_arrays`, or ``None``."""
    if "alternative_t_world_body" not in arrays:
        return None
    return Trajectory(
        arrays["stamps_ns"], arrays["alternative_t_world_body"], arrays["alternative_quat_xyzw"],
        body_frame, world_frame,
    )  # fmt: skip
