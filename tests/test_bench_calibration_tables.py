"""The calibration benchmark's markdown: unresolved-axis labels, the over-seeds summary, notes."""

from benchmarks.calibration_tables import (
    before_offset_handover,
    before_voxel_random,
    runs_suffix,
    summary,
    unresolved,
)


def _row(case: str, seed: int, t_cm: float, r_deg: float, undetermined=()) -> dict:
    return {
        "case": case,
        "train_seed": seed,
        "t_err_cm": t_cm,
        "r_err_deg": r_deg,
        "wall_s": 100.0 * (seed + 1),
        "target": (2.0, 0.5),
        "undetermined": list(undetermined),
    }


def test_unresolved_names_probe_axes_not_excitation_notes():
    row = _row(
        "x",
        0,
        1.0,
        0.1,
        [
            "translation along LiDAR z (resolution flat)",
            "rotation about LiDAR x: a nearby extrinsic scores higher (not converged)",
            "rotation about LiDAR x (resolution 2.91 deg)",
            "weakly excited: rotation about y",
        ],
    )
    assert unresolved(row) == "rx tz"
    assert unresolved(_row("x", 0, 1.0, 0.1)) == "-"
    held = {**_row("x", 0, 1.0, 0.1), "vertical_hold": {"value_m": 0.0, "source": "none"}}
    assert unresolved(held) == "t-vertical(held)"  # a ground vehicle's height: not estimated


def test_summary_counts_failed_seeds_as_missed():
    rows = [_row("handheld", 0, 0.4, 0.02), _row("handheld", 1, 3.0, 0.02)]
    failed = [{"case": "handheld", "train_seed": 2, "error": "lost track"}]
    md = summary(rows, failed, {"handheld": (2.0, 0.5)})
    line = next(s for s in md.splitlines() if s.startswith("| handheld |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[1:4] == ["2", "1", "1.70 / 3.00"]
    assert cells[5] == "150"  # median wall time of the two results
    assert cells[6].startswith("1/3 met")


def test_restarted_runs_are_marked():
    row = _row("ugv seq 1", 0, 1.0, 0.1)
    assert runs_suffix(row) == "" and runs_suffix({**row, "attempts": None}) == ""
    two = [{"seed": 0, "kept": False}, {"seed": 10007, "kept": True}]
    assert runs_suffix({**row, "attempts": two}) == " (2 runs)"


def test_ground_vehicle_rows_handed_over_without_the_offset_are_named():
    joint = "estimated jointly with the extrinsic, from the rotation-rate correlation"
    old = "narrow enough for the refinement after 1 iterations (sigma <= 2.5 deg / 20 cm)"
    new = "narrow enough for the refinement after 9 iterations (sigma <= 2.5 deg / 20 cm / 10 ms)"
    rows = [
        {**_row("ugv all ct-lidar", 0, 1.0, 0.1), "stop": old, "time_offset_method": joint},
        {**_row("ugv all ct-lidar", 1, 1.0, 0.1), "stop": new, "time_offset_method": joint},
        {**_row("ugv seq 1", 0, 1.0, 0.1), "stop": "budget", "time_offset_method": joint},
        {**_row("ugv held", 0, 1.0, 0.1), "stop": old, "time_offset_method": "known: held"},
        {**_row("handheld", 0, 1.0, 0.1), "stop": old, "time_offset_method": joint},
    ]
    note = before_offset_handover(rows)
    assert "ugv all ct-lidar (seed 0)" in note
    for other in ("(seed 1)", "ugv seq 1", "ugv held", "handheld"):
        assert other not in note
    assert before_offset_handover(rows[1:]) == ""


def test_rows_measured_with_the_earliest_voxel_point_are_counted_and_named():
    old = _row("ugv drive ouster-os1-16 ct-lidar", 0, 8.5, 0.13)  # no voxel_point: earliest
    kept = {**_row("handheld with backend.options.voxel_point=earliest", 0, 0.3, 0.02)}
    kept["voxel_point"] = "earliest"
    new = {**_row("ugv drive ouster-os1-16 ct-lidar", 1, 8.3, 0.09), "voxel_point": "random"}
    note = before_voxel_random([old, kept, new])
    assert "2 of 3 rows" in note
    assert "default cases among them: ugv drive ouster-os1-16 ct-lidar (seed 0)." in note
    other = {**_row("ugv all", 1, 1.0, 0.1)}  # every row of its case old: named without seeds
    both = before_voxel_random([old, new, other])
    assert "them: ugv all, ugv drive ouster-os1-16 ct-lidar (seed 0)." in both
    assert "handheld" not in note.split("default cases among them")[1]  # named by its case
    assert before_voxel_random([new]) == ""
