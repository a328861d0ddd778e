"""Runs every benchmark in turn: ``python -m benchmarks [NAME ...]`` (``make bench``).

Each benchmark prints its table and writes JSON under ``benchmarks/results/``. Names are the module
suffixes (``sim_speed``, ``policies``, ``calibration`` …); with none, all run, cheapest first. Extra
arguments after ``--`` go to every module (e.g. ``-- --quick`` where supported).
"""

from __future__ import annotations

import subprocess
import sys
import time

#: Cheapest first, so a broken install fails fast.
ORDER = (
    "sim_speed",
    "selection",
    "policies",
    "sim_realism",
    "references",
    "reference_plumbing",
    "backends",
    "demo",
    "e2e",
    "calibration",
    "tests",
)


def main(argv: list[str]) -> int:
    """Runs the named benchmarks (all by default) as subprocesses; returns the worst exit code."""
    extra: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, extra = argv[:i], argv[i + 1 :]
    names = argv or list(ORDER)
    unknown = [n for n in names if n not in ORDER]
    if unknown:
        print(f"error: unknown benchmark(s) {unknown} — fix: choose from {list(ORDER)}")
        return 2
    worst = 0
    for name in names:
        t0 = time.perf_counter()
        print(f"== benchmarks.bench_{name}", flush=True)
        rc = subprocess.call([sys.executable, "-m", f"benchmarks.bench_{name}", *extra])
        print(f"== bench_{name}: exit {rc} after {time.perf_counter() - t0:.0f} s", flush=True)
        worst = max(worst, rc)
    return worst


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
