from __future__ import annotations

import sys
from pathlib import Path

import pytest

from l2calib.errors import PluginError
from l2calib.plugins import EntryPointLike, PluginRegistry, env_entry_points

sys.path.insert(0, str(Path(__file__).parent))
import fake_plugins  # noqa: E402


def _source(entries):
    def source(group):
        return [e for e in entries if e.group == group]

    return source


def ep(name, value, group="l2calib.backends", dist="dist-a"):
    return EntryPointLike(name, group, value, dist)


def test_discovery_loads_specs_with_distribution():
    reg = PluginRegistry(_source([ep("fake-lio", "fake_plugins:BACKEND")]))
    found = reg.discover("l2calib.backends")
    spec, dist = found["fake-lio"]
    assert spec is fake_plugins.BACKEND and dist == "dist-a"
    assert reg.names("l2calib.references") == []
    built = spec.build({"voxel_size_m": 0.25}, seed=3)
    assert built[0] == "built" and built[1].voxel_size_m == 0.25 and built[2] == {"seed": 3}


def test_get_imports_only_the_requested_plugin():
    loaded = []

    def loader(name):
        def load():
            loaded.append(name)
            return fake_plugins.BACKEND

        return load

    entries = [
        EntryPointLike("fake-lio", "l2calib.backends", "x:y", "d", loader("fake-lio")),
        EntryPointLike("heavy", "l2calib.backends", "x:z", "d", loader("heavy")),
    ]
    reg = PluginRegistry(_source(entries))
    assert reg.get("l2calib.backends", "fake-lio") is fake_plugins.BACKEND
    assert loaded == ["fake-lio"]
    assert reg.names("l2calib.backends") == ["fake-lio", "heavy"]
    assert loaded == ["fake-lio"]  # listing names imports nothing


def test_duplicate_names_are_rejected():
    reg = PluginRegistry(
        _source(
            [
                ep("fake-lio", "fake_plugins:BACKEND", dist="dist-a"),
                ep("fake-lio", "fake_plugins:BACKEND", dist="dist-b"),
            ]
        )
    )
    with pytest.raises(PluginError, match="registered 2 times .*dist-a.*dist-b"):
        reg.discover("l2calib.backends")
    with pytest.raises(PluginError, match="registered 2 times"):
        reg.get("l2calib.backends", "fake-lio")


def test_wrong_type_and_mismatched_name_are_rejected():
    reg = PluginRegistry(_source([ep("fake-lio", "fake_plugins:NOT_A_SPEC")]))
    with pytest.raises(PluginError, match="is a dict, not a PluginSpec"):
        reg.get("l2calib.backends", "fake-lio")
    reg = PluginRegistry(_source([ep("fake-lio", "fake_plugins:MISNAMED")]))
    with pytest.raises(PluginError, match="loads spec 'other-name'"):
        reg.get("l2calib.backends", "fake-lio")
    reg = PluginRegistry(_source([ep("fake-ref", "fake_plugins:BACKEND", "l2calib.references")]))
    with pytest.raises(PluginError, match="loads spec 'fake-lio' of group 'l2calib.backends'"):
        reg.get("l2calib.references", "fake-ref")


def test_import_failure_names_the_plugin():
    reg = PluginRegistry(_source([ep("broken", "no_such_module_xyz:SPEC")]))
    with pytest.raises(
        PluginError, match="plugin 'broken' in l2calib.backends .* failed to import"
    ):
        reg.get("l2calib.backends", "broken")


def test_missing_plugins_give_install_hints():
    reg = PluginRegistry(_source([]))
    with pytest.raises(PluginError) as err:
        reg.get("l2calib.backends", "iekf")
    assert "not installed" in str(err.value) and "l2calib-backends" in str(err.value)
    with pytest.raises(PluginError, match="no plugin named 'nope'"):
        reg.get("l2calib.backends", "nope")
    with pytest.raises(PluginError, match="unknown plugin group"):
        reg.get("l2calib.nothing", "x")


def test_env_var_registration():
    eps = env_entry_points("l2calib.backends", fake_plugins.ENV)
    assert [(e.name, e.value) for e in eps] == [("fake-lio", "fake_plugins:BACKEND")]
    with pytest.raises(PluginError, match="malformed"):
        env_entry_points("l2calib.backends", "l2calib.backends-no-equals")


def test_env_var_reaches_the_installed_registry(monkeypatch):
    from l2calib import plugins

    monkeypatch.setenv(plugins.ENV_VAR, fake_plugins.ENV)
    assert plugins.get_plugin("l2calib.policies", "fake-policy") is fake_plugins.POLICY
