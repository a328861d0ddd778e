from __future__ import annotations

import pytest
from io_scenes import make_scene


@pytest.fixture
def scene_factory(tmp_path):
    def make(**kw):
        return make_scene(tmp_path, **kw)

    return make
