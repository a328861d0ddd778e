from __future__ import annotations

from pydantic import BaseModel

from l2calib.plugins import PluginSpec


class FakeOptions(BaseModel):
    delay_s: float = 0.0


def _make(config, **context):
    from fakes import FakeBackend

    return FakeBackend(delay_s=config.delay_s)


FAKE = PluginSpec("fake-lio", "l2calib.backends", FakeOptions, _make, "fake backend for tests")
