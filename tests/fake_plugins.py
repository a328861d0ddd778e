"""Plugin specs used by the tests through L2CALIB_PLUGINS or a fake entry-point source."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from l2calib.plugins import PluginSpec


class FakeOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    voxel_size_m: float = Field(0.5, gt=0)
    iterations: int = 4


def _make(config, **context):
    return ("built", config, context)


BACKEND = PluginSpec("fake-lio", "l2calib.backends", FakeOptions, _make, "a fake backend")
REFERENCE = PluginSpec("fake-ref", "l2calib.references", FakeOptions, _make, "a fake reference")
POLICY = PluginSpec("fake-policy", "l2calib.policies", FakeOptions, _make, "a fake policy")
NOT_A_SPEC = {"name": "fake-lio"}
MISNAMED = PluginSpec("other-name", "l2calib.backends", FakeOptions, _make, "wrong name")

ENV = (
    "l2calib.backends:fake-lio=fake_plugins:BACKEND;"
    "l2calib.references:fake-ref=fake_plugins:REFERENCE;"
    "l2calib.policies:fake-policy=fake_plugins:POLICY"
)
