from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

from l2calib.errors import ConfigError
from l2calib.plugins import ENV_VAR
from l2calib.recipe import Recipe, apply_overrides, dump_recipe, filled_plugin_options, load_recipe

sys.path.insert(0, str(Path(__file__).parent))
import fake_plugins  # noqa: E402

FAKE = {
    "reference": {"name": "fake-ref"},
    "backend": {"name": "fake-lio"},
    "policy": {"name": "fake-policy"},
}


@pytest.fixture
def fake_env(monkeypatch):
    monkeypatch.setenv(ENV_VAR, fake_plugins.ENV)


def _write(tmp_path, data, name="r.yaml"):
    p = tmp_path / name
    p.write_text(yaml.safe_dump(data))
    return p


def test_defaults_and_overrides(fake_env, tmp_path):
    p = _write(tmp_path, {**FAKE, "train": {"seed": 4}})
    r = load_recipe(p, ["train.seed=7", "selection.budget_s=12.5", "data.imu.topic=/vn100/imu"])
    assert r.train.seed == 7 and r.selection.budget_s == 12.5 and r.data.imu.topic == "/vn100/imu"


def test_unknown_key_names_its_path(fake_env, tmp_path):
    p = _write(tmp_path, {**FAKE, "train": {"sed": 4}})
    with pytest.raises(ConfigError) as err:
        load_recipe(p)
    assert f"{p}: train.sed: unknown key" in str(err.value)
    assert "l2calib recipe dump" in str(err.value)


def test_bad_value_names_its_path_and_value(fake_env, tmp_path):
    p = _write(tmp_path, {**FAKE, "data": {"lidar": {"stamp_position": "middle"}}})
    with pytest.raises(ConfigError) as err:
        load_recipe(p)
    msg = str(err.value)
    assert "data.lidar.stamp_position: Input should be 'auto', 'start' or 'end'" in msg
    assert "(got 'middle')" in msg
    with pytest.raises(ConfigError, match="selection.window_s: Input should be greater than 0"):
        load_recipe(p, ["data.lidar.stamp_position=end", "selection.window_s=-1"])


def test_plugin_options_are_validated_with_their_path(fake_env, tmp_path):
    bad = {**FAKE, "backend": {"name": "fake-lio", "options": {"voxel_size_m": -1, "x": 1}}}
    with pytest.raises(ConfigError) as err:
        load_recipe(_write(tmp_path, bad))
    msg = str(err.value)
    assert "backend.options.voxel_size_m: Input should be greater than 0 (got -1)" in msg
    assert "backend.options.x: unknown key" in msg


def test_unknown_plugin_is_a_config_error(fake_env, tmp_path):
    with pytest.raises(ConfigError, match="backend.name: no plugin named 'nope'"):
        load_recipe(_write(tmp_path, {**FAKE, "backend": {"name": "nope"}}))


def test_malformed_yaml_and_missing_file(tmp_path):
    p = tmp_path / "bad.yaml"
    p.write_text("train:\n  seed: [1, 2\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:\d+: not valid YAML"):
        load_recipe(p)
    p.write_text("- a\n- b\n")
    with pytest.raises(ConfigError, match="must be a YAML mapping, got list"):
        load_recipe(p)
    with pytest.raises(ConfigError, match="no such recipe file"):
        load_recipe(tmp_path / "missing.yaml")


def test_bad_override_syntax():
    with pytest.raises(ConfigError, match="not of the form key=value"):
        apply_overrides({}, ["train.seed"])
    with pytest.raises(ConfigError, match="'seed' is not a section"):
        apply_overrides({"train": {"seed": 1}}, ["train.seed.x=2"])


def test_dump_is_complete_and_reloads(fake_env, tmp_path):
    recipe = Recipe.model_validate(FAKE)
    filled, notices = filled_plugin_options(recipe)
    assert notices == []
    assert filled.backend.options == {"voxel_size_m": 0.5, "iterations": 4}
    text = dump_recipe(filled)
    reloaded = load_recipe(_write(tmp_path, yaml.safe_load(text)))
    assert reloaded == filled
    for key in ("data:", "selection:", "reference:", "backend:", "policy:", "reward:", "train:"):
        assert key in text


def test_switching_a_plugin_drops_the_options_written_for_the_old_one(caplog, tmp_path):
    import logging

    kiss = {"name": "kiss-icp", "options": {"max_range_m": 70.0, "voxel_size": 0.5}}
    path = _write(tmp_path, {"reference": kiss})
    with caplog.at_level(logging.INFO, logger="l2calib.recipe"):
        recipe = load_recipe(
            path,
            ["reference.options.max_points=2000", "reference.name=ct-lidar"],  # order is free
        )
    assert recipe.reference.name == "ct-lidar"
    assert recipe.reference.options == {"max_points": 2000}  # kiss-icp's voxel_size is gone
    assert "reference.options (max_range_m, voxel_size) are not used" in caplog.text
    same = load_recipe(path, ["reference.name=kiss-icp"])
    assert same.reference.options["voxel_size"] == 0.5  # not a switch: the options stay


def test_the_reference_fallback_is_validated_and_dropped_on_a_switch(caplog):
    import logging

    recipe = load_recipe("livox-mid360-mti300")
    assert recipe.reference.name == "ct-lidar"
    assert recipe.reference.fallback.name == "kiss-icp"
    assert recipe.reference.fallback.options["voxel_size"] == 0.5
    with pytest.raises(ConfigError, match="reference.fallback.options.voxel_size: Input should"):
        load_recipe("livox-mid360-mti300", ["reference.fallback.options.voxel_size=-1"])
    with pytest.raises(ConfigError, match="reference.fallback.name: no plugin named 'nope'"):
        load_recipe("livox-mid360-mti300", ["reference.fallback.name=nope"])
    with caplog.at_level(logging.INFO, logger="l2calib.recipe"):
        gt = load_recipe(
            "livox-mid360-mti300", ["reference.name=gt-file", "reference.options.path=gt.tum"]
        )
    assert gt.reference.fallback is None  # a gt-file the user chose is never replaced
    assert "reference.name=gt-file replaces ct-lidar: its fallback is not used" in caplog.text
    filled, _ = filled_plugin_options(recipe)
    assert filled.reference.fallback.options["deskew_iterations"] == 3  # kiss-icp's defaults
