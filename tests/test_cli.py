from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import yaml

from l2calib import __version__

TESTS = Path(__file__).parent


def run(*args, env_plugins=True):
    import os

    env = dict(os.environ)
    if env_plugins:
        env["L2CALIB_PLUGINS"] = (
            "l2calib.backends:fake-lio=fake_plugins:BACKEND;"
            "l2calib.references:fake-ref=fake_plugins:REFERENCE;"
            "l2calib.policies:fake-policy=fake_plugins:POLICY"
        )
        env["PYTHONPATH"] = str(TESTS) + os.pathsep + env.get("PYTHONPATH", "")
    return subprocess.run(
        [sys.executable, "-m", "l2calib.cli.app", *args], capture_output=True, text=True, env=env
    )


def test_version():
    out = run("--version")
    assert out.returncode == 0 and out.stdout.strip() == f"l2calib {__version__}"


def test_plugins_lists_groups_names_and_distributions():
    out = run("plugins")
    assert out.returncode == 0, out.stderr
    for text in ("l2calib.backends", "fake-lio", "$L2CALIB_PLUGINS", "fake-policy", "fake-ref"):
        assert text in out.stdout


def test_recipe_dump_is_valid_yaml_with_plugin_defaults(tmp_path):
    out = run(
        "recipe",
        "dump",
        "--set",
        "backend.name=fake-lio",
        "--set",
        "reference.name=fake-ref",
        "--set",
        "policy.name=fake-policy",
        "--set",
        "train.seed=9",
    )
    assert out.returncode == 0, out.stderr
    data = yaml.safe_load(out.stdout)
    assert data["train"]["seed"] == 9
    assert data["backend"]["options"] == {"voxel_size_m": 0.5, "iterations": 4}
    p = tmp_path / "r.yaml"
    p.write_text(out.stdout)
    check = run("recipe", "check", str(p))
    assert check.returncode == 0 and "ok" in check.stdout


def test_known_errors_print_one_line_and_exit_1(tmp_path):
    p = tmp_path / "r.yaml"
    p.write_text("train:\n  sed: 1\n")
    out = run("recipe", "check", str(p))
    assert out.returncode == 1
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("error: ") and "train.sed: unknown key" in lines[0]
    assert " — fix: " in lines[0]
