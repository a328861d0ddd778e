"""Bad input gets a clear error (or warning) naming the file, topic or field, and the fix."""

from __future__ import annotations

import shutil

import pytest
from io_bagkit import T0, Msgs

from l2calib.errors import DataError, FormatError
from l2calib.io.imu_reader import DEG, STANDARD_GRAVITY
from l2calib.io.sequences import open_sequence, open_sequences
from l2calib.recipe import DataConfig


def cfg(**lidar) -> DataConfig:
    c = DataConfig()
    for k, v in lidar.items():
        setattr(c.lidar, k, v)
    return c


def test_truncated_ros1_bag(scene_factory, tmp_path):
    scene = scene_factory(vendor="ouster", storage="ros1")
    data = scene.path.read_bytes()
    cut = tmp_path / "cut.bag"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError) as err:
        open_sequence(cut, cfg())
    assert str(cut) in str(err.value) and "rosbag reindex" in str(err.value)


def test_corrupt_ros1_chunk_is_reported_while_reading(scene_factory, tmp_path):
    scene = scene_factory(vendor="ouster", storage="ros1")
    data = bytearray(scene.path.read_bytes())
    mid = len(data) // 3
    data[mid : mid + 4000] = b"\xff" * 4000
    bad = tmp_path / "corrupt.bag"
    bad.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"corrupt\.bag: (cannot open|damaged) bag"):
        open_sequence(bad, cfg())


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_corrupt_ros2_storage_file(scene_factory, storage, tmp_path):
    scene = scene_factory(vendor="hesai", storage=storage)
    files = [p for p in scene.path.iterdir() if p.suffix in (".db3", ".mcap")]
    data = files[0].read_bytes()
    target = tmp_path / f"broken{files[0].suffix}"
    target.write_bytes(data[: len(data) // 3])
    with pytest.raises(FormatError, match=f"broken{files[0].suffix}.*ros2 bag reindex"):
        open_sequence(target, cfg())


def test_not_a_bag(tmp_path):
    (tmp_path / "notes.bag").write_text("hello")
    with pytest.raises(FormatError, match="notes.bag: cannot open bag"):
        open_sequence(tmp_path / "notes.bag")
    with pytest.raises(DataError, match="missing.bag: no such bag"):
        open_sequence(tmp_path / "missing.bag")
    (tmp_path / "dir").mkdir()
    with pytest.raises(DataError, match="without metadata.yaml is not a ROS2 bag"):
        open_sequence(tmp_path / "dir")
    (tmp_path / "x.txt").write_text("")
    with pytest.raises(DataError, match=r"unknown bag format '\.txt'"):
        open_sequence(tmp_path / "x.txt")


def test_missing_topic_names_the_candidates(scene_factory):
    scene = scene_factory(vendor="ouster", lidar_topic="/os_cloud_node/points")
    with pytest.raises(DataError) as err:
        open_sequence(scene.path, cfg())
    msg = str(err.value)
    assert "topic '/points' not found" in msg
    assert "fix: set data.lidar.topic to one of: /os_cloud_node/points" in msg
    seq = open_sequence(scene.path, cfg(), auto_topics=True)  # the only candidate is taken
    assert seq.meta["lidar_topic"] == "/os_cloud_node/points"


def test_wrong_message_type(scene_factory):
    scene = scene_factory(vendor="ouster")
    with pytest.raises(
        DataError,
        match="topic '/imu' has type sensor_msgs/msg/Imu, expected "
        "livox_ros_driver/msg/CustomMsg or .*PointCloud2.*fix: set "
        "data.lidar.topic to one of: /points",
    ):
        open_sequence(scene.path, cfg(topic="/imu"))


def test_all_scans_empty_is_an_error_some_empty_a_warning(scene_factory):
    scene = scene_factory(vendor="velodyne", empty_scans=tuple(range(12)))
    with pytest.raises(
        DataError, match="velodyne_ros1.bag: /points: none of the first 12 scans has a valid point"
    ):
        open_sequence(scene.path, cfg())
    scene = scene_factory(vendor="hesai", empty_scans=(0, 1, 2, 7), storage="mcap", n_scans=16)
    seq = open_sequence(scene.path, cfg())
    assert len(seq.scans.stamps_ns) == 12
    assert seq.meta["time_convention"]["reference"] == "absolute"
    assert any("4 empty scan(s) skipped" in w for w in seq.meta["warnings"])


def test_range_limits_that_drop_everything(scene_factory):
    scene = scene_factory(vendor="ouster")
    with pytest.raises(
        DataError,
        match=r"no scan has valid points \(all NaN, zero, or outside "
        r"\[0.5, 1.0\] m\).*max_range_m",
    ):
        open_sequence(scene.path, cfg(max_range_m=1.0))


def test_cloud_without_time_field(scene_factory):
    scene = scene_factory(vendor="livox_v1")
    with pytest.raises(
        DataError,
        match="no per-point time field.*fields: x, y, z, reflectivity, "
        "tag, line.*CustomMsg.*time_field to .*'none'",
    ):
        open_sequence(scene.path, cfg())
    seq = open_sequence(scene.path, cfg(time_field="none"))
    scan = seq.scans.load(0, 2**62)[0]
    assert scan.offset_s.max() == 0.0


def test_time_field_named_in_recipe_must_exist(scene_factory):
    scene = scene_factory(vendor="ouster")
    with pytest.raises(DataError, match="data.lidar.time_field 'time' is not a field of the cloud"):
        open_sequence(scene.path, cfg(time_field="time"))


def test_gyro_in_deg_s_and_accel_in_g_are_detected_and_converted(scene_factory):
    scene = scene_factory(vendor="ouster", gyro_scale=1 / DEG, accel_scale=1 / STANDARD_GRAVITY)
    seq = open_sequence(scene.path, cfg())
    units = seq.meta["imu_units"]
    assert (units["gyro_unit"], units["accel_unit"]) == ("deg/s", "g")
    st, g, a = scene.imu
    assert abs(seq.imu.gyro_rad_s - g).max() < 1e-9
    assert abs(seq.imu.accel_m_s2 - a).max() < 1e-9


def test_accel_that_is_no_gravity_is_an_error(scene_factory):
    scene = scene_factory(vendor="ouster", accel_scale=0.4)
    with pytest.raises(
        DataError, match="/imu: accelerometer unit unclear.*fix: set data.imu.accel_unit"
    ):
        open_sequence(scene.path, cfg())


def test_imu_gap_is_reported(scene_factory):
    scene = scene_factory(vendor="ouster", imu_drop=(0.4, 0.7))
    seq = open_sequence(scene.path, cfg())
    ((a, b),) = seq.meta["imu_gaps_ns"]
    assert 0.29 < (b - a) / 1e9 < 0.32
    assert any(
        "IMU has 1 gap(s) longer than 0.025 s (longest 0.30" in w for w in seq.meta["warnings"]
    )


def test_lidar_and_imu_that_do_not_overlap(scene_factory):
    scene = scene_factory(vendor="hesai", imu_offset_s=100.0)
    with pytest.raises(
        DataError,
        match="time ranges do not overlap: LiDAR .* IMU .*fix: both "
        "sensors must be stamped on the same clock",
    ):
        open_sequence(scene.path, cfg())


def test_several_bags_get_unique_names(scene_factory, tmp_path):
    scene = scene_factory(vendor="custom", storage="ros1")
    other = tmp_path / "copy"
    other.mkdir()
    shutil.copy(scene.path, other / scene.path.name)
    seqs = open_sequences([scene.path, other / scene.path.name], cfg())
    assert [s.name for s in seqs] == ["custom_ros1", "custom_ros1-2"]
    with pytest.raises(DataError, match="no bag given"):
        open_sequences([])


def test_empty_topic(tmp_path, scene_factory):
    from io_bagkit import write_bag

    m = Msgs(False)
    path = write_bag(
        tmp_path / "imu_only",
        "ros1",
        [
            ("/imu", "sensor_msgs/msg/Imu", T0 + i, m.imu(T0 + i, [0, 0, 0], [0, 0, 9.8]))
            for i in range(3)
        ],
    )
    with pytest.raises(
        DataError,
        match="imu_only.bag: topic '/points' not found.*this bag has no .* topic; record one",
    ):
        open_sequence(path, cfg())
