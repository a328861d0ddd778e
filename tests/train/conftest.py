from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture
def fake_backend_env(monkeypatch):
    """Registers the fake backend as plugin ``fake-lio`` for the duration of a test."""
    from l2calib.plugins import ENV_VAR

    monkeypatch.setenv(ENV_VAR, "l2calib.backends:fake-lio=fake_specs:FAKE")
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
