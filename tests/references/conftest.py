from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from ref_helpers import SimCase, make_case  # noqa: E402


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
def cache_dir(tmp_path_factory) -> Path:
    """One cache for the session, so each KISS-ICP run happens once."""
    return tmp_path_factory.mktemp("reference-cache")
