from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from ref_helpers import SimCase, make_case  # noqa: E402

from l2calib.data import Segment  # noqa: E402


@pytest.fixture(scope="session")
def drive() -> SimCase:
    """5 s ground vehicle in a hall (OS1-16 x512): KISS-ICP tracks it; segment = scans 20-45."""
    return make_case(
        {
            "duration_s": 5.0,
            "seed": 2,
            "world": {"name": "hall"},
            "motion": {"profile": "ugv", "still_start_s": 0.0},
            "lidar": {"model": "ouster-os1-16", "columns": 512},
        },
        first=20,
        last=45,
    )


@pytest.fixture(scope="session")
def sway() -> SimCase:
    """6 s hand-held sway (coarse LiDAR, never odometry): rotation-rich for clock checks."""
    return make_case(
        {
            "duration_s": 6.0,
            "seed": 4,
            "world": {"name": "hall"},
            "motion": {"profile": "handheld", "still_start_s": 0.5},
            "lidar": {"model": "ouster-os1-16", "columns": 64},
        },
        first=10,
        last=50,
    )


@pytest.fixture(scope="session")
def swing() -> SimCase:
    """3 s of the aggressive hand-held swing (mean |ω| ≈ 2 rad/s) that defeats KISS-ICP."""
    return make_case(
        {
            "duration_s": 3.5,
            "seed": 3,
            "world": {"name": "hall"},
            "motion": {"profile": "handheld", "still_start_s": 0.0},
            "lidar": {"model": "ouster-os1-16", "columns": 512},
        },
        first=10,
        last=34,
    )


@pytest.fixture(scope="session")
def lost(swing) -> Segment:
    """The swing's segment with scans 4-9 scattered at random: no odometry can follow it."""
    seg = swing.segment
    rng = np.random.default_rng(0)
    scans = list(seg.scans[:4])
    for s in seg.scans[4:10]:
        pts = rng.uniform(-20, 20, size=s.points_lidar.shape).astype(np.float32)
        scans.append(type(s)(s.stamp_ns, pts, s.offset_s))
    return Segment(seg.name, seg.sequence, seg.start_ns, seg.end_ns, seg.imu, scans)


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory) -> Path:
    """One cache for the session, so each KISS-ICP run happens once."""
    return tmp_path_factory.mktemp("reference-cache")
