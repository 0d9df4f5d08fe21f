"""Bad input to the environments fails with one clear line, and the physics' validity is reported every step.

Actions of the wrong shape or kind, a step after the episode's end, configs of the wrong type at any depth:
each raises before any work is done, naming what is wrong. ``info["loop_closure"]`` is checked against the
simulator's ``loop_closure_error`` computed independently (at the step's end, and after every substep of a
replay that steps one substep at a time), and ``closure_exceeded`` against the reported number.
"""

from __future__ import annotations

import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import ResetNeeded

import vswrist_gym
from vswrist_gym.envs.config import EnvConfigError

IDS = list(vswrist_gym.ENV_IDS)
SHORT = {"episode_s": 0.1}  # 5 control steps: cheap episodes for the end-of-episode tests


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert "\n" not in msg, msg
    return msg


# ----------------------------------------------------------------------------------------------- actions
BAD_ACTIONS = [
    pytest.param(np.zeros((1, 4), np.float32), "shape", id="batched-1x4"),
    pytest.param(np.zeros((2, 2), np.float32), "shape", id="2x2"),
    pytest.param(np.zeros((4, 1, 1), np.float32), "shape", id="4x1x1"),
    pytest.param(np.zeros(3, np.float32), "shape", id="too-short"),
    pytest.param(np.zeros(5), "shape", id="too-long"),
    pytest.param(0.5, "shape", id="scalar"),
    pytest.param([[0.0, 0.0], [0.0, 0.0]], "shape", id="nested-list"),
    pytest.param([[0.0, 0.0], [0.0]], "regular array", id="ragged-list"),
    pytest.param(np.array([0.1 + 0.5j, 0.0, 0.0, 0.0]), "real numbers", id="complex"),
    pytest.param(np.zeros(4, np.complex64), "real numbers", id="complex-zero-imaginary"),
    pytest.param([0.0, None, 0.0, 0.0], "real numbers", id="None-inside"),
    pytest.param(["0", "0", "0", "0"], "real numbers", id="strings"),
    pytest.param(np.array([True, False, True, False]), "real numbers", id="bool"),
    pytest.param(np.array([0.0, np.nan, 0.0, 0.0]), "NaN", id="nan"),
    pytest.param(np.array([0.0, 0.0, -np.inf, 0.0]), "inf", id="inf"),
]


@pytest.mark.parametrize("action, match", BAD_ACTIONS)
def test_bad_actions_raise_one_line_before_any_work(action, match):
    env = gym.make("VSWrist/LoadHold-v0")
    u = env.unwrapped
    env.reset(seed=0)
    state = u.sim.get_state()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. NumPy's ComplexWarning must not be the only signal
        with pytest.raises(ValueError, match=match) as err:
            env.step(action)
    msg = _one_line(err.value)
    assert "action" in msg
    # nothing happened: no physics, no step counted, and the episode goes on with a good action
    np.testing.assert_array_equal(u.sim.get_state(), state)
    assert u._step == 0
    env.step(np.zeros(4, np.float32))
    env.close()


@pytest.mark.parametrize("env_id", IDS)
def test_flattenable_and_complex_actions_raise_on_every_task(env_id):
    env = gym.make(env_id)
    env.reset(seed=0)
    for bad in (np.zeros((1, 4), np.float32), np.zeros((2, 2)), np.zeros(4, np.complex128)):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    env.close()


def test_lists_tuples_and_integer_arrays_are_the_same_action_as_the_array():
    """A Python list or tuple of the right length, or an integer array, is an action: the same one as the
    float array (the episodes stay identical)."""
    forms = [np.array([0.25, -0.5, 0.0, 1.0], np.float32), [0.25, -0.5, 0.0, 1.0], (0.25, -0.5, 0, 1)]
    outs = []
    for form in forms:
        env = gym.make("VSWrist/LoadHold-v0")
        env.reset(seed=3)
        outs.append(env.step(form)[0])
        env.close()
    for o in outs[1:]:
        np.testing.assert_array_equal(o, outs[0])
    env = gym.make("VSWrist/LoadHold-v0")
    env.reset(seed=3)
    env.step(np.array([0, 0, 0, 1], dtype=np.int64))  # integers are real numbers
    env.close()


# ------------------------------------------------------------------------------------------ episode end
def test_step_after_truncation_raises_until_reset():
    env = gym.make("VSWrist/LoadHold-v0", **SHORT)
    u = env.unwrapped
    env.reset(seed=0)
    a = np.zeros(4, np.float32)
    for i in range(u.episode_steps):
        _, _, terminated, truncated, _ = env.step(a)
        assert not terminated
        assert truncated == (i == u.episode_steps - 1)
    with pytest.raises(ResetNeeded, match=r"reset\(\)") as err:
        env.step(a)
    _one_line(err.value)
    assert u._step == u.episode_steps  # nothing stepped
    env.reset(seed=1)
    env.step(a)  # a new episode steps again
    env.close()


def test_step_after_termination_raises_until_reset():
    from vswrist_gym.sim import SimulationError

    env = gym.make("VSWrist/Drill-v0")
    u = env.unwrapped
    env.reset(seed=0)

    def diverge(duration_s, restart_peak=True):
        raise SimulationError("test: unstable")

    u.sim.step = diverge
    _, _, terminated, truncated, info = env.step(np.zeros(4, np.float32))
    assert terminated and not truncated
    assert math.isinf(info["loop_closure"]) and info["closure_exceeded"]  # the opening is unknown
    with pytest.raises(ResetNeeded, match=r"reset\(\)"):
        env.step(np.zeros(4, np.float32))
    env.close()


def test_step_before_the_first_reset_raises():
    env = gym.make("VSWrist/LoadHold-v0")
    with pytest.raises(ResetNeeded, match=r"reset\(\)"):
        env.unwrapped.step(np.zeros(4, np.float32))  # the unwrapped env refuses too, not only the wrapper
    env.close()


# ---------------------------------------------------------------------------------------------- configs
@pytest.mark.parametrize("kwargs, field", [
    ({"config": [1, 2]}, "'config'"),
    ({"config": "reward.energy=0.5"}, "'config'"),
    ({"config": {"randomize": 5}}, "'randomize'"),
    ({"randomize": [1, 2]}, "'randomize'"),
    ({"config": {"reward": 1.0}}, "'reward'"),
    ({"config": {"task": "hard"}}, "'task'"),
    ({"config": {"render": "big"}}, "'render'"),
    ({"config": {"scales": None}}, "'scales'"),
    ({"config": {"randomize": {"spring_K": True}}}, "'randomize.spring_K'"),
    ({"config": {"randomize": {"sensor_noise": [0.1]}}}, "'randomize.sensor_noise'"),
    ({"config": {"randomize": {"spring_K": {"range": 1.1}}}}, "'randomize.spring_K.range'"),
    ({"config": {"randomize": {"sensor_noise": {"posture": "loud"}}}}, "'randomize.sensor_noise.posture'"),
    ({"config": {"reward": {"energy": "high"}}}, "'reward.energy'"),
    ({"config": {"task": {"load_mass": {"low": 0.1}}}}, "'task.load_mass'"),
    ({"config": {"ctrl_dt": {"value": 0.02}}}, "'ctrl_dt'"),
    ({"config": {"closure_warn": "1e-3"}}, "'closure_warn'"),
    ({"config": {"closure_warn": 0.0}}, "'closure_warn'"),
    ({"config": {"closure_truncate": "no"}}, "'closure_truncate'"),
])
def test_configs_of_the_wrong_type_name_the_field(kwargs, field):
    with pytest.raises(EnvConfigError) as err:
        gym.make("VSWrist/LoadHold-v0", **kwargs)
    assert field in _one_line(err.value)


# ----------------------------------------------------------------------------------------- loop closure
@pytest.mark.parametrize("env_id", IDS)
def test_loop_closure_in_info_every_step_finite_and_non_negative(env_id):
    env = gym.make(env_id)
    u = env.unwrapped
    _, info = env.reset(seed=0)
    infos = [info]
    rng = np.random.default_rng(0)
    for _ in range(u.episode_steps):
        _, _, terminated, truncated, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
        infos.append(info)
        # the worst over the period includes its last state, which the simulator computes independently here
        assert info["loop_closure"] >= u.sim.loop_closure_error()
        if terminated or truncated:
            break
    for info in infos:
        c = info["loop_closure"]
        assert isinstance(c, float) and math.isfinite(c) and c >= 0.0
        assert info["closure_exceeded"] == (c > u.cfg["closure_warn"])
    env.close()


def _replayed_per_substep(env_id, actions, seed, **kw):
    """``loop_closure_error`` after every physics substep, stepping one substep at a time: per env step, the
    worst of the state it started from and of every substep's result."""
    env = gym.make(env_id, **kw)
    u = env.unwrapped
    env.reset(seed=seed)
    sim = u.sim
    one = sim.step
    seen: list[float] = [sim.loop_closure_error()]

    def step_checked(duration_s, restart_peak=True):
        for _ in range(int(round(duration_s / sim.timestep))):
            one(sim.timestep)
            seen.append(sim.loop_closure_error())

    sim.step = step_checked
    per_step = []
    for a in actions:
        start = len(seen) - 1  # the state this period starts from
        env.step(a)
        per_step.append(max(seen[start:]))
    env.close()
    return per_step


@pytest.mark.parametrize("env_id, kw", [
    ("VSWrist/LoadHold-v0", {}),  # reads poses only: the last state's check comes from the step's end
    ("VSWrist/Impact-v0", {}),    # reads sensors: the full mj_forward after the step checks the last state
    ("VSWrist/LoadHold-v0", {"randomize": {"latency": {"enabled": True, "range": [0.01, 0.01]}}}),  # 2 calls
])
def test_reported_closure_is_the_worst_over_every_substep(env_id, kw):
    """The native per-substep monitor reports what stepping one substep at a time and calling
    ``loop_closure_error`` after each finds (the same trajectory: the extra ``mj_forward`` calls change
    nothing). Random actions, so the openings vary over orders of magnitude."""
    rng = np.random.default_rng(1)
    actions = [rng.uniform(-1, 1, 4).astype(np.float32) for _ in range(40)]
    env = gym.make(env_id, **kw)
    env.reset(seed=5)
    reported = [env.step(a)[4]["loop_closure"] for a in actions]
    env.close()
    replay = _replayed_per_substep(env_id, actions, 5, **kw)
    # 2 acos(|q.q'|) resolves angles to about 3e-8 rad; C and NumPy may round the dot product differently
    np.testing.assert_allclose(reported, replay, rtol=1e-6, atol=1e-7)
    assert max(reported) > 10 * min(reported)  # the comparison spans real variation


def test_python_fallback_monitor_matches_the_compiled_one():
    from vswrist_gym.model import native
    from vswrist_gym.sim import WristSim

    peaks = []
    for backend in ("c", "python"):
        sim = WristSim("paper_knm", backend=backend)
        try:
            sim.reset(u=(0.2, 0.3), lam=8.0)
            sim.set_motor_references(sim.motor_angles() + [0.3, -0.2, 0.1, 0.5])
            sim.step(0.02)
            peaks.append(sim.loop_closure_peak())
        finally:
            native.install("c")
    assert peaks[0] > 1e-6
    assert peaks[1] == pytest.approx(peaks[0], rel=1e-6, abs=1e-7)


@pytest.mark.parametrize("warn, always, never", [(1e-12, True, False), (10.0, False, True)])
def test_closure_flag_follows_the_configured_threshold(warn, always, never):
    """A threshold below any opening flags every step; one above any possible opening (angles are at most
    pi) flags none; the flag is exactly ``loop_closure > closure_warn``."""
    env = gym.make("VSWrist/Impact-v0", closure_warn=warn)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    flags = []
    for _ in range(20):
        info = env.step(rng.choice([-1.0, 1.0], 4).astype(np.float32))[4]
        assert info["closure_exceeded"] == (info["loop_closure"] > warn)
        flags.append(info["closure_exceeded"])
    assert all(flags) if always else not any(flags)
    env.close()


def test_closure_truncate_ends_the_episode_without_success():
    env = gym.make("VSWrist/LoadHold-v0", closure_warn=1e-12, closure_truncate=True)
    env.reset(seed=0)
    _, _, terminated, truncated, info = env.step(np.zeros(4, np.float32))
    assert truncated and not terminated and info["closure_exceeded"] and not info["is_success"]
    with pytest.raises(ResetNeeded):
        env.step(np.zeros(4, np.float32))
    env.close()
    env = gym.make("VSWrist/LoadHold-v0", closure_truncate=True, **SHORT)  # default threshold: the baseline
    u = env.unwrapped                                                        # runs its episode to the end
    env.reset(seed=0)
    for i in range(u.episode_steps):
        _, _, terminated, truncated, info = env.step(u.reference_to_action(u._target, 0.0))
        assert not info["closure_exceeded"]
    assert truncated and not terminated
    env.close()
