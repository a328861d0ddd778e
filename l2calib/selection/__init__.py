"""Data selection by IMU excitation (paper Sec. III-D).

:func:`window_excitation` scores sliding windows of one sequence; :func:`select_windows` picks
windows across sequences up to a time budget, preferring those that excite the axes the
selection still lacks, and reports per-axis excitation and the weak axes.
:func:`~l2calib.selection.plot.plot_selection` draws the timeline (PNG).

Example:
    >>> from l2calib.selection import select_windows  # doctest: +SKIP
    >>> sel = select_windows(sequences, recipe.selection)  # doctest: +SKIP
    >>> segments = sel.segments(sequences)  # doctest: +SKIP
"""

from __future__ import annotations

from l2calib.selection.excitation import WindowStats, integrate_gyro, window_excitation
from l2calib.selection.greedy import ChosenWindow, Selection, select_windows

__all__ = [
    "ChosenWindow",
    "Selection",
    "WindowStats",
    "integrate_gyro",
    "select_windows",
    "window_excitation",
]
