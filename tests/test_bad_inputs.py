"""Bad inputs a new user produces, each rebuilt from a short simulated bag: exit status + message.

A regression suite for issue 26 (``docs/reliability.md`` has the table): every fault ends in a
clear one-line ``error: … — fix: …`` (exit 1), a documented status, or a resumable interruption,
never in a traceback or a silent success. Each case runs the real ``l2calib`` command in a
subprocess.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

#: Small, fast training settings on the simulator recipe with the simulated truth as reference.
FAST = [
    "--set", "train.candidates_per_iteration=8", "--set", "train.refine_rounds=1",
    "--set", "train.restarts=0", "--set", "selection.window_s=3", "--set", "selection.budget_s=3",
]  # fmt: skip


def l2calib(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """Runs ``l2calib ARGS`` in a subprocess (text output captured)."""
    cmd = [sys.executable, "-m", "l2calib.cli.app", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, cwd=cwd, timeout=300)


def one_error_line(proc: subprocess.CompletedProcess) -> str:
    """The single ``error: … — fix: …`` line of a failed command (and no traceback)."""
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: ") and " — fix: " in lines[0], lines[0]
    return lines[0]


def simulated(out: Path, duration_s: float) -> dict[str, str]:
    """A short simulated hand-held OS1-16 + VN100 bag with its ground truth."""
    from l2calib.sim import SimConfig, simulate, write_run

    cfg = SimConfig.model_validate(
        {
            "duration_s": duration_s,
            "seed": 4,
            "lidar": {"model": "ouster-os1-16", "columns": 256},
            "imu": {"model": "vn100"},
        }
    )
    return write_run(simulate(cfg), out)


@pytest.fixture(scope="module")
def sim6(tmp_path_factory) -> dict[str, str]:
    return simulated(tmp_path_factory.mktemp("sim6"), 6.0)


@pytest.fixture(scope="module")
def sim1(tmp_path_factory) -> dict[str, str]:
    """A 1 s recording: far too short to calibrate."""
    return simulated(tmp_path_factory.mktemp("sim1"), 1.0)


def gt_reference(files: dict[str, str]) -> list[str]:
    return [
        "--set",
        "reference.name=gt-file",
        "--set",
        f"reference.options.path={files['gt_lidar']}",
    ]


IMU, CLOUD = "sensor_msgs/msg/Imu", "sensor_msgs/msg/PointCloud2"


def edit_bag(src: str, dst: Path, edit) -> Path:
    """Copies a simulated ROS1 bag through ``edit(msgtype, k, msg) -> msg or None (dropped)``.

    ``k`` counts the messages of that type; ``msg`` is deserialised (IMU and point clouds only).
    """
    from rosbags.rosbag1 import Reader, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    seen: dict[str, int] = {}
    with Reader(src) as reader, Writer(dst) as writer:
        conns = {
            c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
            for c in reader.connections
        }
        for conn, t_ns, raw in reader.messages():
            if conn.msgtype in (IMU, CLOUD):
                k = seen[conn.msgtype] = seen.get(conn.msgtype, -1) + 1
                msg = edit(conn.msgtype, k, store.deserialize_ros1(raw, conn.msgtype))
                if msg is None:
                    continue
                raw = store.serialize_ros1(msg, conn.msgtype)
            writer.write(conns[conn.id], t_ns, raw)
    return dst


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec


def set_stamp(msg, ns: int):
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 10**9)
    return msg


def rewrite_bag(src: str, dst: Path, shift_imu_s: float) -> Path:
    """Copies a simulated ROS1 bag, moving every IMU header stamp by ``shift_imu_s``."""
    shift_ns = int(round(shift_imu_s * 1e9))

    def edit(msgtype, k, msg):
        return set_stamp(msg, stamp_ns(msg) + shift_ns) if msgtype == IMU else msg

    return edit_bag(src, dst, edit)


def drop_imu(src: str, dst: Path, from_s: float, to_s: float) -> Path:
    """Copies a bag without the IMU messages ``from_s``-``to_s`` s after the first one."""
    first: list[int] = []

    def edit(msgtype, k, msg):
        if msgtype != IMU:
            return msg
        first.append(stamp_ns(msg)) if not first else None
        rel = (stamp_ns(msg) - first[0]) / 1e9
        return None if from_s <= rel < to_s else msg

    return edit_bag(src, dst, edit)


def spoil_scans(src: str, dst: Path, which: set[int], how: str) -> Path:
    """Copies a bag with scans ``which`` empty (``how="empty"``) or all-NaN (``"nan"``)."""
    import dataclasses

    import numpy as np

    def edit(msgtype, k, msg):
        if msgtype != CLOUD or k not in which:
            return msg
        if how == "empty":
            return dataclasses.replace(msg, width=0, row_step=0, data=np.zeros(0, np.uint8))
        rec = msg.data.copy().reshape(msg.width * msg.height, msg.point_step)
        offsets = {f.name: f.offset for f in msg.fields}
        for axis in "xyz":
            rec[:, offsets[axis] : offsets[axis] + 4] = np.frombuffer(
                np.float32(np.nan).tobytes(), np.uint8
            )
        return dataclasses.replace(msg, data=rec.reshape(-1))

    return edit_bag(src, dst, edit)


# --------------------------------------------------------------------------- unwritable --out
UNWRITABLE = {
    "missing /proc entry": "/proc/l2calib-x",
    "sysfs": "/sys/l2calib-x",
    "below a file": "/etc/hostname/l2calib-x",
}


@pytest.mark.parametrize("where", sorted(UNWRITABLE))
def test_unwritable_out_fails_before_calibrating(sim6, where):
    out = UNWRITABLE[where]
    t0 = time.monotonic()
    proc = l2calib("calibrate", "simulator", "--bag", sim6["bag"], "--out", out, *FAST)
    line = one_error_line(proc)
    assert f"--out {out}:" in line and "fix: pass a --out in a place you can write to" in line
    assert "reading recordings" not in proc.stdout  # before any work
    assert time.monotonic() - t0 < 60


@pytest.mark.parametrize(
    "args",
    [
        ["demo", "--duration", "2"],
        ["simulate", "--duration", "2"],
        ["reference", "simulator", "--bag", "{bag}"],
    ],
    ids=["demo", "simulate", "reference"],
)
def test_unwritable_out_of_other_commands(sim6, args):
    args = [a.format(bag=sim6["bag"]) for a in args]
    proc = l2calib(*args, "--out", "/proc/l2calib-x/out.tum")
    line = one_error_line(proc)
    assert "--out /proc/l2calib-x/out.tum:" in line and "cannot write in /proc" in line
    assert "simulating" not in proc.stdout + proc.stderr


def test_unwritable_json_of_inspect(sim6):
    line = one_error_line(l2calib("inspect", sim6["bag"], "--json", "/proc/l2calib-x/r.json"))
    assert "--json /proc/l2calib-x/r.json:" in line


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_out_directory(sim6, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    line = one_error_line(
        l2calib("calibrate", "simulator", "--bag", sim6["bag"], "--out", ro / "c", *FAST)
    )
    assert f"--out {ro / 'c'}:" in line and "Permission denied" in line


# --------------------------------------------------------------------------- recipes and --set
def test_recipe_dump_with_a_plugin_missing_its_required_option():
    line = one_error_line(l2calib("recipe", "dump", "simulator", "--set", "reference.name=gt-file"))
    assert "--set reference.name=gt-file: reference.options.path: Field required" in line
    assert "--set reference.options.path=VALUE" in line  # the fix names the field
    assert "recipes/simulator.yaml" not in line  # the built-in file is not the source


def test_a_bad_set_value_is_attributed_to_the_set():
    line = one_error_line(l2calib("recipe", "check", "simulator", "--set", "train.seed=abc"))
    assert line.startswith("error: --set train.seed=abc: train.seed: Input should be")
    assert "simulator.yaml" not in line


def test_a_bad_value_in_the_file_still_names_the_file(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text("train:\n  seed: abc\n")
    line = one_error_line(l2calib("recipe", "check", p, "--set", "train.workers=1"))
    assert f"{p}: train.seed" in line and "--set" not in line.split(" — fix")[0]


def test_empty_recipe_file_fails_check(tmp_path):
    p = tmp_path / "empty.yaml"
    p.write_text("")
    line = one_error_line(l2calib("recipe", "check", p))
    assert f"{p}: the recipe file is empty" in line and "l2calib recipe dump" in line


# --------------------------------------------------------------------------- inspect
def test_normal_bag_has_no_clock_warning(sim6):
    proc = l2calib("inspect", sim6["bag"])
    assert proc.returncode == 0, proc.stderr
    assert "different clocks" not in proc.stdout and "LiDAR-IMU overlap: 6.00 s" in proc.stdout


def test_disjoint_streams_say_they_do_not_overlap(sim6, tmp_path):
    bag = rewrite_bag(sim6["bag"], tmp_path / "disjoint.bag", shift_imu_s=-990.0)
    proc = l2calib("inspect", bag)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "overlap: -" not in proc.stdout
    assert "LiDAR-IMU overlap: none" in proc.stdout and "do not overlap" in proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error: ") and "time ranges do not overlap" in last
    assert "fix: both sensors must be stamped on the same clock" in last


def test_inspect_warns_a_one_second_recording_is_too_short(sim1):
    proc = l2calib("inspect", sim1["bag"], "--recipe", "simulator")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = " ".join(proc.stdout.split())
    assert (
        "too short or too still to calibrate: only 0.9 s of usable data, far below one "
        "selection window (selection.window_s = 5 s)" in text
    )
    assert "fix: record at least 5 s of motion" in text
    assert re.search(r"motion: \d+\.\d s of 0\.9 s overlap; selectable 0\.9 s", text), text


#: The 6 s bag's first second is still: 5 s windows do not fit beside it, 3 s windows do.
WINDOW3 = ["--recipe", "simulator", "--set", "selection.window_s=3"]


def test_inspect_finds_enough_motion_in_a_normal_bag(sim6):
    proc = l2calib("inspect", sim6["bag"], "--recipe", "simulator", *WINDOW3)
    assert proc.returncode == 0, proc.stderr
    text = " ".join(proc.stdout.split())
    assert "selectable 3.0 s (selection.window_s 3 s" in text
    assert "too short or too still" not in text


# --------------------------------------------------------------------------- faulty streams
@pytest.mark.parametrize("how", ["empty", "nan"])
def test_empty_or_nan_scans_are_dropped_counted_and_worked_around(sim6, tmp_path, how):
    bag = spoil_scans(sim6["bag"], tmp_path / f"{how}.bag", {12, 25, 40, 51}, how)
    proc = l2calib("select", bag, *WINDOW3, "--plot", tmp_path / "s.png")
    assert proc.returncode == 0, proc.stdout + proc.stderr  # was 1: "no window was selected"
    text = " ".join(proc.stdout.split())
    assert "4 empty / all-NaN scan(s) of /ouster/points dropped on reading" in text
    assert "chosen windows (3.0 s of 10.0 s)" in text and "LiDAR has" not in text


IMU_GAP = r"IMU gap of 2\.0\d\d s at 1\.99\d s \(stamp 17\d{8}\.\d{3} s\) on /imu/data"


def test_imu_gap_selection_uses_either_side_and_says_so(sim6, tmp_path):
    bag = drop_imu(sim6["bag"], tmp_path / "gap.bag", 2.0, 4.0)
    sel_json = tmp_path / "s.json"
    proc = l2calib("select", bag, *WINDOW3, "--json", sel_json, "--plot", tmp_path / "s.png")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = " ".join(proc.stdout.split())
    assert re.search(IMU_GAP + r": no window spans a gap", text), text
    spans = json.loads(sel_json.read_text())["spans"]
    assert spans
    gap_start = int(re.search(r"stamp (\d+\.\d+) s", text).group(1).replace(".", "")) * 10**6
    for _, a, b in spans:  # every chosen span lies on one side of the 2 s gap
        assert b <= gap_start or a >= gap_start + 2 * 10**9


def test_imu_gap_without_room_for_a_window_is_named(sim6, tmp_path):
    bag = drop_imu(sim6["bag"], tmp_path / "gap.bag", 2.0, 4.0)
    line = one_error_line(l2calib("calibrate", "simulator", "--bag", bag, "--out", tmp_path / "o"))
    assert "the data selection found no window to calibrate on" in line
    assert re.search(IMU_GAP, line), line
    assert "still or too short" not in line


def test_imu_gap_with_selection_disabled_is_no_ground_truth_problem(sim6, tmp_path):
    bag = drop_imu(sim6["bag"], tmp_path / "gap.bag", 2.0, 4.0)
    args = [*gt_reference(sim6), "--set", "selection.enabled=false"]
    line = one_error_line(
        l2calib("calibrate", "simulator", "--bag", bag, "--out", tmp_path / "o", *args)
    )
    assert re.search(IMU_GAP + ": with selection.enabled=false", line), line
    assert "fix: set selection.enabled=true" in line and "cut the bag" in line
    assert "quaternion" not in line  # was: a quaternion-order problem of the ground-truth file


def test_swapped_stamps_are_reported_and_reordered(sim6, tmp_path):
    # LiDAR messages 20/21 and 40/41 and IMU messages 300/301 carry each other's header stamps
    shift = {(CLOUD, 20): 1, (CLOUD, 21): -1, (CLOUD, 40): 1, (CLOUD, 41): -1}
    shift |= {(IMU, 300): 1, (IMU, 301): -1}
    period = {CLOUD: 100_000_000, IMU: 5_000_000}

    def edit(msgtype, k, msg):
        return set_stamp(msg, stamp_ns(msg) + shift.get((msgtype, k), 0) * period[msgtype])

    bag = edit_bag(sim6["bag"], tmp_path / "swapped.bag", edit)
    proc = l2calib("inspect", bag, "--recipe", "simulator")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = " ".join(proc.stdout.split())
    assert "/ouster/points: 2 message(s) arrive with a stamp earlier than the previous one" in text
    assert "/imu/data: 1 message(s) arrive with a stamp earlier than the previous one" in text
    assert "fix: they are reordered by stamp" in text
    proc = l2calib("select", bag, *WINDOW3, "--plot", tmp_path / "s.png")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    text = " ".join(proc.stdout.split())
    assert "/imu/data: repaired stamps/values {'reordered': 1" in text
    assert "chosen windows (3.0 s of 10.0 s)" in text and "gap of" not in text


# --------------------------------------------------------------------------- simulate
def test_simulate_refuses_an_existing_out_before_simulating(sim6):
    out = Path(sim6["bag"]).parent
    t0 = time.monotonic()
    proc = l2calib("simulate", "--out", out, "--duration", "60")
    line = one_error_line(proc)
    assert "already exists" in line and "--overwrite" in line
    assert "scans" not in proc.stderr  # no simulation summary: it stopped before the sweep
    assert time.monotonic() - t0 < 60


# --------------------------------------------------------------------------- too little data
def test_one_second_recording_stops_before_training(sim1, tmp_path):
    out = tmp_path / "out"
    args = [*gt_reference(sim1), "--set", "train.max_iterations=2"]
    proc = l2calib("calibrate", "simulator", "--bag", sim1["bag"], "--out", out, *FAST, *args)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    text = " ".join(proc.stdout.split())  # rich wraps long lines
    assert "status: not-calibrated — stopped before training" in text
    assert (
        "only 0.9 s of usable data, far below one selection window (selection.window_s = 3 s): "
        "record at least 3 s of motion" in text
    )
    assert "the selected data is too still" in text and "swing the rig" in text
    # no reference, no training: no checkpoint, no iteration, no extrinsic on screen or on disk
    stages = [line for line in proc.stdout.splitlines() if line.startswith("• ")]
    assert stages[-1] == "• 1 segment(s), 0.9 s of data"  # no reference, odometry or training
    assert not (out / "checkpoint.pt").exists() and "T_imu_lidar" not in text
    written = (out / "calibration.yaml").read_text()
    assert "# NOT CALIBRATED: calibrate stopped before training" in written
    data = yaml.safe_load(written)
    assert data["status"] == "not-calibrated" and len(data["status_reasons"]) == 2
    assert data["training"]["iterations"] == 0 and data["data"]["selected_s"] == 0.9
    assert "T_imu_lidar" not in data and "fast_lio" not in data and "urdf" not in data


def test_a_not_calibrated_file_is_refused_by_its_readers(sim1, tmp_path):
    files, out = sim1, tmp_path / "out"
    proc = l2calib("calibrate", "simulator", "--bag", files["bag"], "--out", out)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    calib = out / "calibration.yaml"
    line = one_error_line(l2calib("evaluate", "--extrinsic", calib, "--bag", files["bag"]))
    assert line.startswith(
        f"error: {calib}: status not-calibrated: calibrate stopped before training and wrote "
        "no extrinsic; status_reasons[0]: only 0.9 s of usable data"
    )
    assert "fix: record the motion its status_reasons ask for" in line
    line = one_error_line(
        l2calib("calibrate", "simulator", "--bag", files["bag"], "--out", out, "--resume")
    )
    assert f"{out}: nothing to resume: that run stopped before training" in line


@pytest.mark.slow
def test_calibrate_trains_on_a_bag_with_nan_scans(sim6, tmp_path):
    bag = spoil_scans(sim6["bag"], tmp_path / "nan.bag", {12, 25, 40, 51}, "nan")
    out = tmp_path / "out"
    args = [*FAST, *gt_reference(sim6), "--set", "train.max_iterations=2"]
    proc = l2calib("calibrate", "simulator", "--bag", bag, "--out", out, *args)
    assert proc.returncode in (0, 3), proc.stdout + proc.stderr  # was 1: no informative window
    text = " ".join(proc.stdout.split())
    assert "4 empty / all-NaN scan(s) of /ouster/points dropped on reading" in text
    assert yaml.safe_load((out / "calibration.yaml").read_text())["training"]["iterations"] == 2


# --------------------------------------------------------------------------- interruptions
def _start_calibration(files: dict[str, str], out: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "l2calib.cli.app", "calibrate", "simulator"]
    cmd += ["--bag", files["bag"], "--out", str(out), *FAST, *gt_reference(files)]
    cmd += ["--set", "train.max_iterations=500", "--set", "train.checkpoint_every=1"]
    # its own process group, as a shell job: a Ctrl-C reaches the workers too
    return subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
    )


def _interrupt_after_first_checkpoint(proc: subprocess.Popen, out: Path, sig: int):
    deadline = time.monotonic() + 240
    while not (out / "checkpoint.pt").is_file():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline
        time.sleep(0.1)
    t0 = time.monotonic()
    os.killpg(proc.pid, sig)
    stdout, stderr = proc.communicate(timeout=60)
    return stdout, stderr, time.monotonic() - t0


@pytest.mark.slow
def test_sigint_keeps_the_checkpoint_and_resume_finishes(sim6, tmp_path):
    out = tmp_path / "out"
    proc = _start_calibration(sim6, out)
    _, stderr, waited = _interrupt_after_first_checkpoint(proc, out, signal.SIGINT)
    assert proc.returncode == 130, stderr
    assert waited < 5.0
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr
    line = stderr.strip().splitlines()[-1]
    assert line.startswith("interrupted at iteration ") and "(SIGINT;" in line
    head, _, command = line.partition(" — resume with: ")
    assert command.startswith("l2calib calibrate simulator --bag ") and command.endswith("--resume")
    assert (out / "checkpoint.pt").is_file()
    iteration = int(head.split()[3])
    # the printed command, with a budget the run has already reached (budgets may change)
    resumed = l2calib(*command.split()[1:], "--set", f"train.max_iterations={iteration}")
    assert resumed.returncode in (0, 3), resumed.stdout + resumed.stderr
    text = " ".join(resumed.stdout.split())
    assert f"resuming the first PPO run (seed 0) at iteration {iteration} from" in text
    assert yaml.safe_load((out / "calibration.yaml").read_text())["training"]["iterations"] == (
        iteration
    )


@pytest.mark.slow
def test_sigterm_exits_143(sim6, tmp_path):
    out = tmp_path / "out"
    proc = _start_calibration(sim6, out)
    _, stderr, waited = _interrupt_after_first_checkpoint(proc, out, signal.SIGTERM)
    assert proc.returncode == 143, stderr
    assert waited < 5.0 and "Traceback" not in stderr
    assert "(SIGTERM;" in stderr and "--resume" in stderr


def test_a_killed_workers_fd_sharing_error_prints_no_traceback(monkeypatch, capsys):
    """After an interruption, multiprocessing's fd-sharing thread may report a worker killed
    mid-transfer through ``sys.excepthook``: dropped; any other error still prints."""
    from l2calib import interrupt

    monkeypatch.setattr(sys, "excepthook", sys.__excepthook__)
    interrupt.stop_workers(object())  # no workers: only the hook is installed
    namespace: dict = {}
    code = "def serve():\n    raise ConnectionResetError('worker gone')\n"
    exec(compile(code, "/usr/lib/python3/multiprocessing/resource_sharer.py", "exec"), namespace)
    for raise_it, shown in ((namespace["serve"], False), (lambda: 1 / 0, True)):
        try:
            raise_it()
        except Exception:
            sys.excepthook(*sys.exc_info())
        assert ("Traceback" in capsys.readouterr().err) is shown
