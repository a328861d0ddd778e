from __future__ import annotations

from pydantic import BaseModel

from l2calib.plugins import PluginSpec


class FakeOptions(BaseModel):
    pass


def _make(config, **context):
    from fakes import FakeBackend

    return FakeBackend()


FAKE = PluginSpec("fake-lio", "l2calib.backends", FakeOptions, _make, "fake backend for tests")
