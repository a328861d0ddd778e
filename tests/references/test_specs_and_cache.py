"""Entry points of the built-in references, recipe options, and the cache's location and format."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from l2calib.plugins import discover, get_plugin
from l2calib.recipe import Recipe, filled_plugin_options, recipe_from_dict
from l2calib.references.cache import ReferenceCache, cache_key, default_root


def test_the_built_in_references_are_registered():
    found = discover("l2calib.references")
    for name in ("kiss-icp", "ct-lidar", "gt-file", "rtk"):
        spec, dist = found[name]
        assert spec.group == "l2calib.references" and dist == "l2calib"


def test_recipe_exposes_the_kiss_icp_config():
    recipe = recipe_from_dict(
        {"reference": {"name": "kiss-icp", "options": {"voxel_size": 0.5, "deskew_iterations": 2}}}
    )
    filled, _ = filled_plugin_options(recipe)
    opts = filled.reference.options
    assert opts["voxel_size"] == 0.5 and opts["margin_s"] == 1.0 and "max_range_m" in opts
    spec = get_plugin("l2calib.references", "kiss-icp")
    assert spec.config.model_validate(opts).kiss_config().mapping.voxel_size == 0.5
    rtk = filled_plugin_options(Recipe(reference={"name": "rtk"}))[0].reference.options
    assert rtk["kiss_icp"]["deskew_iterations"] == 3 and rtk["lever_arm_m"] == [0.0, 0.0, 0.0]


def test_cache_root_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("L2CALIB_CACHE", str(tmp_path / "c"))
    assert default_root() == tmp_path / "c" / "references"
    monkeypatch.delenv("L2CALIB_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert default_root() == tmp_path / "x" / "l2calib" / "references"


def test_cache_round_trip_keys_and_a_missing_array(tmp_path, caplog):
    cache = ReferenceCache(tmp_path)
    k1, k2 = cache_key({"a": 1, "b": [1, 2]}), cache_key({"b": [1, 2], "a": 1})
    assert k1 == k2 and cache_key({"a": 2, "b": [1, 2]}) != k1
    arrays = {"x": np.arange(5, dtype=np.int64), "y": np.eye(3)}
    calls = []

    def compute():
        calls.append(1)
        return arrays

    out, hit = cache.get_or_compute(k1, compute, {"what": "test"})
    assert not hit and len(calls) == 1
    out, hit = cache.get_or_compute(k1, compute)
    assert hit and len(calls) == 1 and np.array_equal(out["y"], np.eye(3))
    npz, header = cache.paths(k1)
    np.savez(npz, x=arrays["x"])  # consistent file, but not what the header describes
    text = header.read_text()
    import hashlib
    import json

    head = json.loads(text)
    head["sha256"] = hashlib.sha256(npz.read_bytes()).hexdigest()
    header.write_text(json.dumps(head))
    with caplog.at_level(logging.WARNING, logger="l2calib.references"):
        out, hit = cache.get_or_compute(k1, compute)
    assert not hit and len(calls) == 2 and "corrupted" in caplog.text
    disabled = ReferenceCache(tmp_path / "off", enabled=False)
    disabled.get_or_compute(k1, compute)
    assert not (tmp_path / "off").exists()


@pytest.mark.parametrize("bad", [{"deskew_iterations": 0}, {"margin_s": -1}, {"voxel": 1}])
def test_bad_kiss_icp_options_name_the_field(bad):
    from l2calib.errors import ConfigError

    with pytest.raises(ConfigError, match="reference.options." + next(iter(bad))):
        recipe_from_dict({"reference": {"name": "kiss-icp", "options": bad}})
