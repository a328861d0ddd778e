"""The test suite's wall time, as ``make test`` runs it (the README promises < 15 min on 2 cores).

Run: ``python -m benchmarks.bench_tests`` (also the last step of ``make bench``). Runs
``python -m pytest -q`` in a fresh process and writes the wall time, the counts from pytest's
closing line, the slowest tests and the machine to ``benchmarks/results/tests.json``.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.machine import machine_info

RESULTS = Path(__file__).parent / "results" / "tests.json"
ROOT = Path(__file__).parent.parent
TARGET_S = 15 * 60


def main() -> None:
    """Runs the suite once and records it."""
    before = machine_info()
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "--durations=10", "-p", "no:cacheprovider"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    wall = time.monotonic() - t0
    lines = proc.stdout.strip().splitlines()
    closing = lines[-1] if lines else ""
    counts = {k: int(v) for v, k in re.findall(r"(\d+) (passed|failed|skipped|errors?)", closing)}
    slowest = [ln.strip() for ln in lines if re.match(r"^\d+\.\d+s (call|setup)", ln.strip())]
    failed = [ln.split()[1] for ln in lines if ln.startswith(("FAILED ", "ERROR "))]
    row = {
        "benchmark": "bench_tests",
        "command": "python -m pytest -q",
        "exit_code": proc.returncode,
        "wall_s": round(wall, 1),
        "target_s": TARGET_S,
        "passed": proc.returncode == 0 and wall <= TARGET_S,
        "counts": counts,
        "closing_line": closing,
        "failed": failed,
        "slowest": slowest,
        "machine": before,
        "load_after": machine_info()["load"],
    }
    RESULTS.write_text(json.dumps(row, indent=1))
    print(f"test suite: {closing} — {wall:.0f} s (target < {TARGET_S} s) on {before['cores']} "
          f"cores, load {before['load']}")  # fmt: skip
    sys.exit(0 if row["passed"] else 1)


if __name__ == "__main__":
    main()
