"""Checking before any work that an output path can be written.

A run that computes for minutes and then fails to write its result wastes the time; an
``OSError`` traceback does not say which option to change. :func:`check_writable` tries what the
run will do — create the directory and a file in it — in a throw-away place, and names the option
and the fix.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from l2calib.errors import OutputError


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists."""
    path = Path(path).absolute()
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable(path: str | Path, option: str = "--out", kind: str = "directory") -> Path:
    """Fails with a one-line error unless ``path`` can be created and written.

    Args:
        path: The output directory (``kind="directory"``) or file (``kind="file"``; its directory
            is checked, and the file itself must not be a directory).
        option: The command-line option that named ``path`` (used in the message).
        kind: ``directory`` or ``file``.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        OutputError: naming ``option``, ``path``, what is in the way and how to fix it.
    """
    path = Path(path)
    example = "./calib-out" if kind == "directory" else f"./{path.name}"
    fix = f"pass a {option} in a place you can write to (e.g. {option} {example})"
    if kind == "file" and path.is_dir():
        raise OutputError(f"{option} {path}: is a directory, not a file", fix=fix)
    target = path if kind == "directory" else path.parent
    if target.exists() and not target.is_dir():
        raise OutputError(f"{option} {path}: {target} exists and is not a directory", fix=fix)
    base = _nearest_existing(target)
    if not base.is_dir():
        raise OutputError(
            f"{option} {path}: {base} is a file, so no directory can be made below it", fix=fix
        )
    try:  # what the run will do: make directories and write files (removed again at once)
        with tempfile.TemporaryDirectory(prefix=".l2calib-write-test-", dir=base) as tmp:
            (Path(tmp) / "probe").write_bytes(b"")
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise OutputError(f"{option} {path}: cannot write in {base} ({reason})", fix=fix) from None
    return path
