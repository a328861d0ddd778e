"""The time-offset benchmark judges each offset against its zero-offset twin (same scans)."""

from benchmarks.bench_time_offset import _means_table, key, verdicts


def _row(offset_ms: float, estimate: bool, t_cm: float, seed: int = 0, twin: bool = False) -> dict:
    row = {
        "profile": "handheld",
        "reference": "ct-lidar",
        "offset_ms": offset_ms,
        "estimate": estimate,
        "train_seed": seed,
        "t_err_cm": t_cm,
        "r_err_deg": 0.03,
        "evaluations": 1000,
    }
    if estimate:
        row.update(start="rates", offset_error_ms=0.2, time_offset_s=offset_ms / 1000)
    if twin:
        row["imu_restamped"] = True
    return row


def test_an_offset_is_judged_by_its_twin_not_by_the_zero_offset_recording():
    zero = _row(0.0, False, 0.05)  # another recording: other scans, another reference
    twin = _row(20.0, False, 0.60, twin=True)  # the +20 ms scans, IMU re-stamped to 0
    on = _row(20.0, True, 0.75)
    v = verdicts([zero, twin, on])
    assert v[key(on)] == "met"  # 0.75 <= 0.60 + 0.2; against the 0 ms recording it would miss
    assert key(twin) != key(_row(20.0, False, 0.60))  # a twin does not replace an "off" row


def test_without_a_twin_the_verdict_says_it_compared_other_scans():
    v = verdicts([_row(0.0, False, 0.05), _row(20.0, True, 0.75)])
    assert v[key(_row(20.0, True, 0.75))] == "MISSED (0.75 cm > 0.25) vs the 0 ms recording"
    means = "\n".join(_means_table([_row(0.0, False, 0.05), _row(20.0, True, 0.75)]))
    assert "(other scans)" in means


def test_a_twin_has_the_same_scans_and_poses_with_the_imu_on_the_lidar_clock():
    import numpy as np

    from benchmarks.bench_time_offset import restamped
    from l2calib.sim import SimConfig, simulate

    cfg = {"duration_s": 2.0, "seed": 0, "lidar": {"columns": 64}, "rig": {"time_offset_s": 0.02}}
    run = simulate(SimConfig.model_validate(cfg))
    twin = restamped(run)
    assert twin.scans is run.scans and twin.time_offset_s == 0.0
    assert np.array_equal(twin.imu.stamps_ns, run.imu.stamps_ns - 20_000_000)
    t = run.gt_lidar.stamps_ns[2:5]
    assert np.array_equal(twin.lidar_poses(t), run.lidar_poses(t))  # the same motion
    # a scan stamp now reads the same instant on both clocks
    assert np.allclose(twin.imu_poses(t, clock="imu") @ twin.T_imu_lidar, twin.lidar_poses(t))


def test_a_twin_with_the_true_offset_held_wins_over_a_restamped_one():
    restamped = _row(50.0, False, 0.43, twin=True)  # other segments were selected
    known = {**_row(50.0, False, 0.66), "offset_known": True}  # the recording's own segments
    on = _row(50.0, True, 0.68)
    assert key(known) not in (key(restamped), key(_row(50.0, False, 0.66)))
    for rows in ([restamped, known, on], [known, restamped, on]):
        assert verdicts(rows)[key(on)] == "met"  # judged by the known twin, whatever the order
    assert verdicts([restamped, on])[key(on)].startswith("MISSED")
