"""The calibration benchmark's tables: the console table, the markdown rows and summary, notes.

Split from :mod:`benchmarks.bench_calibration` (which runs the cases): everything here reads
rows only (``benchmarks/results/calibration.json``'s), so ``--render`` and the tests need no
simulator. The notes name rows measured before a change that moved results, by each row's
recorded date or stop reason.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

import numpy as np
from rich.table import Table

#: The rig column of rows measured before the rig was recorded.
OS1_16_NAME = "ouster-os1-16 + vn100"


def console_table(rows: list[dict[str, Any]]) -> Table:
    t = Table(title="calibration from no initial guess (simulated rigs)")
    for col in (
        "case",
        "seed",
        "|Δt| x/y/z cm",
        "|Δr| r/p/y deg",
        "t cm",
        "r deg",
        "wall s",
        "evals",
        "target",
    ):
        t.add_column(col)
    for r in rows:
        ok = ""
        if r["target"]:
            ok = (
                "met"
                if r["t_err_cm"] <= r["target"][0] and r["r_err_deg"] <= r["target"][1]
                else "MISSED"
            )
        t.add_row(
            r["case"],
            str(r["train_seed"]),
            " / ".join(f"{v:.2f}" for v in r["dt_cm"]),
            " / ".join(f"{v:.3f}" for v in r["dr_deg"]),
            f"{r['t_err_cm']:.2f}",
            f"{r['r_err_deg']:.3f}",
            f"{r['wall_s']:.0f}",
            str(r["evaluations"]),
            ok,
        )
    return t


_AXIS = re.compile(r"^(rotation about|translation along) LiDAR ([xyz])")


def unresolved(row: dict[str, Any]) -> str:
    """The axes the run's resolution probe could not pin down, as ``rx ty …`` (``-``: none).

    ``(disagrees!)`` marks a run warned that the odometry and the reference still disagree at
    its result (a wrong reference, or a search stopped at a local optimum).
    """
    axes = set()
    for item in row.get("undetermined", []):
        if m := _AXIS.match(item):
            axes.add(("r" if m[1].startswith("rotation") else "t") + m[2])
    if row.get("vertical_hold"):
        axes.add("t-vertical(held)")
    if row.get("warnings"):
        axes.add("(disagrees!)")
    return " ".join(sorted(axes)) or "-"


def runs_suffix(row: dict[str, Any]) -> str:
    """`` (2 runs)`` when PPO restarted after a failed agreement check (evaluations: all runs)."""
    attempts = row.get("attempts") or []
    return f" ({len(attempts)} runs)" if len(attempts) > 1 else ""


def markdown_rows(rows: list[dict[str, Any]]) -> str:
    cols = (
        "case | rig | seed | data s | Δt x/y/z cm | Δr r/p/y deg | t cm | r deg | wall s | evals"
        " | unresolved"
    )
    lines = [f"| {cols} |", "|" + "---|" * len(cols.split("|"))]
    for r in sorted(rows, key=lambda r: (r["case"], r["train_seed"])):
        dt = " / ".join(f"{v:.2f}" for v in r["dt_cm"])
        dr = " / ".join(f"{v:.3f}" for v in r["dr_deg"])
        lines.append(
            f"| {r['case']} ({r.get('reference', '')}) | {r.get('rig', OS1_16_NAME)} | "
            f"{r['train_seed']} | {r['data_s']} | "
            f"{dt} | {dr} | "
            f"{r['t_err_cm']:.2f} | {r['r_err_deg']:.3f} | {r['wall_s']:.0f} | "
            f"{r['evaluations']}{runs_suffix(r)} | {unresolved(r)} |"
        )
    return "\n".join(lines) + "\n"


def summary(
    rows: list[dict[str, Any]],
    failed: list[dict[str, Any]],
    targets: dict[str, tuple[float, float] | None],
) -> str:
    """Per case over its training seeds: mean and worst errors, how many seeds met the target.

    A failed run (no result) counts as a seed that missed the target; ``targets`` maps a case
    name to its ``(cm, deg)`` target or ``None``.
    """
    names = sorted({r["case"] for r in rows} | {f["case"] for f in failed})
    lines = [
        "\nOver training seeds (mean / worst; wall time is the median, on whatever load the rows"
        " record):\n",
        "| case | seeds | failed | t cm | r deg | wall s | target |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in names:
        rs = [r for r in rows if r["case"] == name]
        n_failed = sum(f["case"] == name for f in failed)
        t = [r["t_err_cm"] for r in rs]
        a = [r["r_err_deg"] for r in rs]
        errors = (
            f"{np.mean(t):.2f} / {max(t):.2f} | {np.mean(a):.3f} / {max(a):.3f}" if rs else "- | -"
        )
        wall = f"{np.median([r['wall_s'] for r in rs]):.0f}" if rs else "-"
        met, target = "-", targets.get(name)
        if target:
            n = sum(r["t_err_cm"] <= target[0] and r["r_err_deg"] <= target[1] for r in rs)
            met = f"{n}/{len(rs) + n_failed} met ({target[0]:g} cm, {target[1]:g}°)"
        lines.append(f"| {name} | {len(rs)} | {n_failed} | {errors} | {wall} | {met} |")
    return "\n".join(lines) + "\n"


#: ``backend.options.start_biases: auto`` landed then: before it the filters started with zero
#: IMU biases everywhere; ``auto`` now estimates them on well-excited (hand-held) data.
START_BIASES_AUTO = "2026-12-04 15:20"
#: The gyro bias's integration changed then (same method, other rounding: other PPO paths).
START_BIASES_FAST = "2026-12-04 17:05"
#: The IEKF / GTSAM propagation stopped re-integrating the stretch past a segment's last IMU
#: sample then (candidates with a positive time offset were penalised at each segment's end).
END_OF_IMU_FIX = "2026-12-04 18:55"


def names(rows: list[dict[str, Any]], keep: Callable[[dict[str, Any]], bool]) -> str:
    """``case (seed n)`` of the rows ``keep`` accepts, sorted and comma-separated."""
    return ", ".join(sorted({f"{r['case']} (seed {r['train_seed']})" for r in rows if keep(r)}))


def dated(
    rows: list[dict[str, Any]], prefix: str, lo: str, hi: str, reference: str | None = None
) -> str:
    """``case (seed n)`` of the rows whose case starts with ``prefix``, measured in ``[lo, hi)``
    (the machine's date), and with ``reference`` as reference if given; comma-separated."""
    return names(
        rows,
        lambda r: (
            r["case"].startswith(prefix)
            and lo <= r.get("machine", {}).get("date", "") < hi
            and (reference is None or r.get("reference") == reference)
        ),
    )


def before_start_biases(rows: list[dict[str, Any]]) -> str:
    """A note naming the hand-held rows measured before the current start-bias code."""
    zero = dated(rows, "handheld", "", START_BIASES_AUTO)
    earlier = dated(rows, "handheld", START_BIASES_AUTO, START_BIASES_FAST)
    before_fix = sum(r.get("machine", {}).get("date", "") < END_OF_IMU_FIX for r in rows)
    md = ""
    if before_fix:
        md += (
            f"\n{before_fix} of {len(rows)} rows were measured before {END_OF_IMU_FIX}, when a "
            "filter window ending past a segment's last IMU sample integrated that stretch "
            "again on every extra step of the batch: candidates with a positive time offset "
            "(estimated by default) were penalised at each segment's last scan "
            "(docs/time_offset.md). Rows after it carry a later date.\n"
        )
    if zero:
        md += (
            f"\nMeasured before `backend.options.start_biases: auto` ({START_BIASES_AUTO}; the "
            "filters started with zero IMU biases, which `auto` now estimates on hand-held data; "
            f"uav and ugv rows are unaffected): {zero}.\n"
        )
    if earlier:
        md += (
            f"\nMeasured with the start biases estimated by the code before {START_BIASES_FAST} "
            "(the same method, the gyro integrated per candidate: the same estimate up to "
            f"rounding, which sends PPO along another path): {earlier}.\n"
        )
    return md


#: ``ct-lidar``'s vehicle prior (``noise_rot_deg`` / ``noise_rate_rad_s``: ``auto``) landed then:
#: before it the ground vehicles' LiDAR-only references used the general motion prior.
VEHICLE_PRIOR = "2026-12-07 05:00"


def before_vehicle_prior(rows: list[dict[str, Any]]) -> str:
    """A note naming the ground-vehicle LiDAR-only rows measured before the vehicle prior."""
    old = dated(rows, "ugv", "", VEHICLE_PRIOR, reference="ct-lidar")
    if not old:
        return ""
    return (
        f"\nMeasured before `ct-lidar`'s vehicle prior ({VEHICLE_PRIOR}; their references used "
        f'the general motion prior, docs/references.md, "The vehicle prior"): {old}.\n'
    )


def before_offset_handover(rows: list[dict[str, Any]]) -> str:
    """A note naming the ground-vehicle rows whose PPO handed over on rotation and translation
    alone, the time offset estimated (before ``PLANAR_RATE_START``'s
    ``train.handover_time_offset_sigma_s``, session 44)."""
    old = names(
        rows,
        lambda r: (
            r["case"].startswith("ugv")
            and str(r.get("stop", "")).startswith("narrow enough")
            and not str(r.get("stop", "")).endswith("ms)")
            and str(r.get("time_offset_method", "")).startswith("estimated jointly")
        ),
    )
    if not old:
        return ""
    return (
        "\nMeasured before ground vehicles' hand-over also waited for the time offset's spread "
        "(PPO handed over on rotation and translation alone; `PLANAR_RATE_START` in "
        'l2calib/train/vertical_hold.py, docs/backends.md, "The hand-over and the time offset"): '
        f"{old}.\n"
    )


def before_voxel_random(rows: list[dict[str, Any]]) -> str:
    """A note counting the rows whose backend kept the earliest point of each voxel (rows
    without ``voxel_point``: before ``backend.options.voxel_point: random``, session 48)."""
    old = [r for r in rows if r.get("voxel_point", "earliest") == "earliest"]
    if not old:
        return ""
    named = [r for r in old if "voxel_point=" not in r["case"]]
    fresh = {r["case"] for r in rows if r.get("voxel_point", "earliest") != "earliest"}
    seeds: dict[str, list[int]] = {}
    for r in named:
        seeds.setdefault(r["case"], []).append(r["train_seed"])
    cases = [  # a case with rows of both kinds names its old seeds
        f"{c} (seed {', '.join(map(str, sorted(seeds[c])))})" if c in fresh else c
        for c in sorted(seeds)
    ]
    return (
        f"\n{len(old)} of {len(rows)} rows were measured with the backend keeping the earliest "
        "fired point of each voxel (the default before 2026-12-07 23:15, "
        "`backend.options.voxel_point`; now a random one: on ground vehicles the earliest "
        "point's side of a voxel follows the sweep's direction and moved the lateral lever arm "
        'by up to 2 cm, docs/backends.md, "Which point each voxel keeps"); default cases among '
        f"them: {', '.join(cases) or 'none'}.\n"
    )


def render(results: dict[str, Any], targets: dict[str, tuple[float, float] | None]) -> str:
    """The markdown of a results JSON: rows, the over-seeds summary, notes, failed runs.

    ``targets``: each case's ``(cm, deg)`` target or ``None`` (:func:`summary`).
    """
    rows, failed = results["rows"], results.get("failed", [])
    md = markdown_rows(rows) + summary(rows, failed, targets)
    md += before_start_biases(rows) + before_vehicle_prior(rows) + before_offset_handover(rows)
    md += before_voxel_random(rows)
    if failed:
        md += "\nFailed (no result):\n\n" + "".join(
            f"- {r['case']} (seed {r['train_seed']}): {r['error']}\n" for r in failed
        )
    return md
