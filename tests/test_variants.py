"""Task variants on the literal `paper` springs (vswrist_gym.envs.variants): the load scaling rule and its files."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym  # noqa: F401
from vswrist_gym.envs import variants
from vswrist_gym.envs.config import EnvConfigError, load_env_config
from vswrist_gym.kinematics import WristKinematics
from vswrist_gym.params import load_params


def _stiffest_by_energy(preset: str) -> tuple[float, float]:
    """(stiffness, N m/rad; energy, J) at home at the environment's stiffest command, from the springs' potential
    energy alone: the motors held where the internal torque lam_max N puts them, V(u) = sum of the sinh springs'
    energies 2 K delta0 (cosh(delta/delta0) - 1) at the legs' exact inverse kinematics, its Hessian by central
    differences (the complete static stiffness, load term included, without the analytic stiffness code)."""
    env = gym.make("VSWrist/LoadHold-v0", config={"params": preset})
    lam = env.unwrapped.stiffness_map.to_lam(1.0)
    env.close()
    p = load_params(preset)
    K, d0 = p.spring.K, p.spring.delta0
    kin = WristKinematics(p)
    home = np.zeros(2)
    # spring torque on the link -2K sinh(delta/delta0) = lam N  ->  delta; motors at theta = q1 - delta
    delta = -d0 * np.arcsinh(lam * kin.internal_torque_basis(home) / (2.0 * K))
    theta = kin.joint_angles(home)[0::4] - delta

    def V(u):
        dq = kin.joint_angles(np.asarray(u, dtype=float))[0::4] - theta
        return float(np.sum(2.0 * K * d0 * (np.cosh(dq / d0) - 1.0)))

    h = 1e-3
    hess = [(V([h, 0]) - 2 * V(home) + V([-h, 0])) / h ** 2, (V([0, h]) - 2 * V(home) + V([0, -h])) / h ** 2]
    return float(np.mean(hess)), V(home)


def test_scales_are_the_presets_stiffest_stiffness_and_energy_ratios():
    s_paper, e_paper = _stiffest_by_energy("paper")
    s_knm, e_knm = _stiffest_by_energy("paper_knm")
    # the presets' readings: 0.0094 / 9.4 N m/rad unloaded, the stiffest command about 3 / 27 N m/rad
    assert 2.5 < s_paper < 3.5 and 22.0 < s_knm < 32.0
    force_scale, energy_scale = variants.scales("paper")
    assert force_scale == pytest.approx(s_paper / s_knm, rel=2e-3)
    assert energy_scale == pytest.approx(e_paper / e_knm, rel=1e-6)


def test_variant_files_are_current_and_scale_every_load():
    assert variants.main(["--check"]) == 0, "run python -m vswrist_gym.envs.variants --write"
    fs, es = variants.scales("paper")
    for task in ("LoadHold", "Polish", "Impact", "Insertion", "Drill"):
        over, base = variants.variant_config(task), load_env_config(variants.stem(task))
        assert over["params"] == "paper"
        keys = [(k, fs) for k in variants.FORCE_KEYS_COMMON + variants.FORCE_KEYS[variants.stem(task)]]
        keys += [(k, es) for k in variants.ENERGY_KEYS_COMMON + variants.ENERGY_KEYS.get(variants.stem(task), ())]
        for dotted, factor in keys:
            a, b = over, base
            for k in dotted.split("."):
                a, b = a[k], b[k]
            assert np.allclose(np.asarray(a, dtype=float), factor * np.asarray(b, dtype=float), rtol=1e-3), dotted
        env = gym.make(f"VSWrist/{task}-v0", config=over)  # a valid configuration
        assert env.unwrapped.nominal_params.spring.K == pytest.approx(0.004)
        env.close()


def test_no_variant_for_hammer():
    with pytest.raises(EnvConfigError, match="no 'paper' variant of task 'Hammer'"):
        variants.scaled_overrides("Hammer")
    with pytest.raises(EnvConfigError, match="no 'paper' variant of task 'Hammer'"):
        variants.variant_config("Hammer")


def test_probe_levels_map_the_rule_commands():
    from vswrist_gym.tools.probe import within

    policy = within(lambda obs: np.array([0.1, 0.2, 0.3, obs], dtype=np.float32), (0.0, 1.0))
    assert [float(policy(s)[-1]) for s in (-1.0, 0.0, 1.0)] == [0.0, 0.5, 1.0]
    assert [float(policy(s)[0]) for s in (-1.0, 1.0)] == pytest.approx([0.1, 0.1])
