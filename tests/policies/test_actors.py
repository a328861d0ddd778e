"""Policy plugins: TorchRL contract (keys, shapes, dtypes), ClipPPOLoss, init, readouts."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest
import torch
from pydantic import ValidationError
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives import ClipPPOLoss

from l2calib.errors import ConfigError
from l2calib.geometry import euler_rpy_to_matrix, rotation_angle
from l2calib.plugins import discover, get_plugin
from l2calib.recipe import ExtrinsicPrior
from l2calib_policies.joint import BinghamExtrinsic, GaussianExtrinsic

F64 = torch.float64
NAMES = ["bingham", "gaussian"]


def build(name: str, **kw):
    opts = kw.pop("options", {})
    return get_plugin("l2calib.policies", name).build(opts, **{"action_dim": 7, "seed": 0, **kw})


def sample(policy, n: int):
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        return policy.actor(policy.observation((n,)))


def test_plugins_are_discoverable_and_spec_module_is_light():
    found = discover("l2calib.policies")
    assert {"bingham", "gaussian"} <= set(found)
    assert found["bingham"][1] == "l2calib-policies"
    code = (
        "import sys, l2calib_policies.specs as s; s.BINGHAM, s.GAUSSIAN; "
        "print(any(m.split('.')[0] in ('torch', 'torchrl', 'tensordict') for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("action_dim", [7, 8])
def test_actor_follows_the_environment_contract(name, action_dim):
    policy = build(name, action_dim=action_dim)
    td = sample(policy, 6)
    assert td["action"].shape == (6, action_dim) and td["action"].dtype == F64
    assert torch.allclose(td["action"][:, :4].norm(dim=-1), torch.ones(6, dtype=F64), atol=1e-12)
    assert policy.log_prob_key == "action_log_prob"
    assert td["action_log_prob"].shape == (6,)
    dist = policy.actor.get_dist(td)
    assert isinstance(dist, BinghamExtrinsic if name == "bingham" else GaussianExtrinsic)
    assert torch.allclose(dist.log_prob(td["action"]), td["action_log_prob"])
    value = policy.value(td)["state_value"]
    assert value.shape == (6, 1) and value.dtype == F64
    # Nested batch dims work too (e.g. [envs, candidates]).
    assert sample(policy, 1).shape == (1,)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        nested = policy.actor(policy.observation((2, 3)))
    assert nested["action"].shape == (2, 3, action_dim)
    assert nested["action_log_prob"].shape == (2, 3)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("prior", [None, ExtrinsicPrior(rpy_deg=(10.0, -20.0, 170.0))])
def test_clip_ppo_loss_trains_every_parameter(name, prior):
    policy = build(name, action_dim=8, prior=prior)
    td = sample(policy, 16)
    td["advantage"] = torch.randn(16, 1, dtype=F64)
    td["value_target"] = torch.randn(16, 1, dtype=F64)
    loss = ClipPPOLoss(policy.actor, policy.value, entropy_coeff=1e-3)
    assert loss.tensor_keys.sample_log_prob == "action_log_prob"
    assert loss.tensor_keys.action == "action"
    out = loss(td)
    assert torch.isfinite(out["entropy"]).all()
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    for pname, p in policy.named_parameters():
        if pname == "value.module.weight":  # multiplies the all-zero observation
            continue
        if pname == "params_net.quat_raw" and name == "bingham" and prior is None:
            # Exactly uniform start (z = 0): log p does not depend on q0 yet; the
            # concentrations (non-zero gradient at z = 0) move first.
            assert torch.equal(p.grad, torch.zeros_like(p.grad))
            continue
        assert p.grad is not None and torch.isfinite(p.grad).all(), pname
        assert p.grad.abs().sum() > 0, pname


@pytest.mark.parametrize("name", NAMES)
def test_init_from_prior_and_readouts(name):
    prior = ExtrinsicPrior(
        translation_m=(0.65, -0.372, -0.016),
        rpy_deg=(180.0, 90.0, 0.0),
        sigma_translation_m=0.05,
        sigma_rotation_deg=4.0,
    )
    policy = build(name, action_dim=8, prior=prior)
    mode = policy.mode()
    T = mode.T_imu_lidar
    assert T.shape == (4, 4) and T.dtype == F64
    R_prior = euler_rpy_to_matrix(torch.deg2rad(torch.tensor(prior.rpy_deg, dtype=F64)))
    assert rotation_angle(R_prior.T @ T[:3, :3]).item() < 1e-9
    assert torch.allclose(T[:3, 3], torch.tensor(prior.translation_m, dtype=F64))
    assert mode.time_offset_s == 0.0
    unc = policy.uncertainty()
    assert torch.allclose(unc.rotation_sigma_deg, torch.full((3,), 4.0, dtype=F64), rtol=0.03)
    assert torch.allclose(unc.rotation_sigma_rad, torch.deg2rad(unc.rotation_sigma_deg))
    assert torch.allclose(unc.translation_sigma_m, torch.full((3,), 0.05, dtype=F64))
    assert unc.time_offset_sigma_s == pytest.approx(0.02)
    # Samples spread as the readout says (rotation about body axes).
    td = sample(policy, 20_000)
    dist = policy.distribution()
    y = dist.rotation.body_coordinates(td["action"][:, :4]) if name == "bingham" else None
    if y is not None:
        assert torch.allclose(2 * (y[:, :3] ** 2).mean(0).sqrt(), unc.rotation_sigma_rad, rtol=0.03)


def test_no_idea_init_is_uniform_rotation_and_wide_translation():
    policy = build("bingham")
    unc = policy.uncertainty()
    # Uniform on S³: E[y_i²] = 1/4, so 2·sqrt(E[y_i²]) = 1 rad on every axis.
    assert torch.allclose(unc.rotation_sigma_rad, torch.ones(3, dtype=F64), rtol=1e-3)
    assert torch.allclose(unc.translation_sigma_m, torch.full((3,), 0.5, dtype=F64))
    z = policy.distribution().rotation.concentration
    assert bool((z == 0).all())  # exactly uniform
    assert policy.mode().T_imu_lidar.shape == (4, 4)
    g = build("gaussian").uncertainty().rotation_sigma_deg
    assert bool((g > 40).all()) and bool((g < 80).all())


@pytest.mark.parametrize("name", NAMES)
def test_seed_makes_sampling_reproducible_and_independent_of_global_rng(name):
    a = build(name, seed=5)
    b = build(name, seed=5)
    torch.manual_seed(0)
    xa = sample(a, 8)["action"]
    torch.manual_seed(123)
    xb = sample(b, 8)["action"]
    assert torch.equal(xa, xb)
    assert not torch.equal(xa, sample(build(name, seed=6), 8)["action"])


def test_deterministic_interaction_returns_the_mode():
    policy = build("bingham", action_dim=8)
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        a = policy.actor(policy.observation((3,)))["action"]
    assert torch.allclose(a, policy.distribution().mode.expand(3, 8))


def test_translation_bound_and_separate_floors():
    opts = {
        "translation_bound_m": 0.3,
        "min_translation_sigma_m": 0.01,
        "min_rotation_sigma_deg": 1.0,
    }
    policy = build("bingham", options=opts)
    net = policy.params_net
    with torch.no_grad():
        net.translation.loc_raw.fill_(100.0)  # far beyond the bound
        net.translation.log_sigma_raw.fill_(-50.0)  # far below the translation floor
    d = policy.distribution()
    assert bool((d.loc.abs() <= 0.3).all())
    assert torch.allclose(d.scale, torch.full((3,), 0.01, dtype=F64), rtol=1e-6)
    # The rotation is untouched by the translation floor/bound, and has its own floor.
    assert torch.allclose(
        policy.uncertainty().rotation_sigma_rad, torch.ones(3, dtype=F64), rtol=1e-3
    )
    with torch.no_grad():
        net.conc_raw.fill_(1e3)  # far beyond the rotation floor
    sigma = policy.uncertainty().rotation_sigma_deg
    assert torch.allclose(sigma, torch.ones(3, dtype=F64), rtol=1e-3)


def test_errors_name_the_field_and_the_fix():
    with pytest.raises(ConfigError, match="action_dim must be 7 or 8"):
        build("bingham", action_dim=6)
    prior = ExtrinsicPrior(translation_m=(0.5, 0.0, 0.0))
    with pytest.raises(ConfigError, match="outside the bound") as exc:
        build("bingham", prior=prior, options={"translation_bound_m": 0.2})
    assert "translation_bound_m" in exc.value.fix
    with pytest.raises(ConfigError, match="min_rotation_sigma_deg"):
        build("gaussian", prior=ExtrinsicPrior(sigma_rotation_deg=0.01))
    with pytest.raises(ValidationError, match="min_translation_sigma_m"):
        build("bingham", options={"init_translation_sigma_m": 0.01, "min_translation_sigma_m": 0.1})
    with pytest.raises(ValidationError):
        build("gaussian", options={"no_such_option": 1})


def test_state_dict_round_trip():
    a = build("bingham", action_dim=8)
    with torch.no_grad():
        a.params_net.quat_raw.copy_(torch.tensor([0.1, 0.2, 0.3, 0.9], dtype=F64))
    b = build("bingham", action_dim=8)
    b.load_state_dict(a.state_dict())
    assert torch.allclose(a.mode().T_imu_lidar, b.mode().T_imu_lidar)
    assert math.isfinite(float(b.distribution().entropy().detach()))


@pytest.mark.parametrize("name", NAMES)
def test_time_offset_starts_where_the_reference_measured_it(name):
    policy = build(name, action_dim=8, init_time_offset_s=0.05)
    assert policy.mode().time_offset_s == pytest.approx(0.05, abs=1e-12)
    offsets = sample(policy, 4000)["action"][:, 7]
    assert float(offsets.mean()) == pytest.approx(0.05, abs=0.002)  # σ0 = 20 ms: ±3σ/√n
    with pytest.raises(ConfigError, match="outside the bound"):
        build(name, action_dim=8, init_time_offset_s=0.3)  # default bound 0.2 s
