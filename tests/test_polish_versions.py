"""VSWrist/Polish-v0 and VSWrist/Polish-v1 differ exactly in how the normal force is read (CHANGELOG.md).

The reference readings are computed here without the environment's force code: a copy of the world's MjData,
taken before each control step, is stepped one substep at a time with MuJoCo's sensors on, reading the surface's
touch sensor (the summed normal force of the contacts in its zone) after every substep and once more at the
period's end state. v1's ``contact_force`` must be the mean of the per-substep readings, v0's the end state's.
"""

from __future__ import annotations

import copy
import warnings

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import vswrist_gym
from vswrist_gym.agents.analytic import AnalyticAgent
from vswrist_gym.envs.config import EnvConfigError

# no latency, so the motor references hold over the whole period and the copy can replay it from data.ctrl
CONFIG = {"randomize": {"latency": {"enabled": False}}}


def _make(env_id, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # gymnasium: v0 is out of date, as it should say
        return gym.make(env_id, **kw)


def _touch_readings(u, before: mujoco.MjData) -> tuple[list[float], float]:
    """(touch sensor after each substep of the period, touch sensor at the period's end state) from ``before``,
    a copy of ``u``'s MjData at the period's start, with ``u``'s motor references of that period."""
    m, d = u.model, before
    d.ctrl[:] = u.data.ctrl
    saved = m.opt.disableflags
    m.opt.disableflags = saved & ~int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
    try:
        per_substep = []
        for _ in range(u.n_substeps):
            mujoco.mj_step(m, d)  # its forward pass evaluates the sensors at the substep's start state
            per_substep.append(float(d.sensordata[u._touch_adr]))
        mujoco.mj_forward(m, d)
        end = float(d.sensordata[u._touch_adr])
    finally:
        m.opt.disableflags = saved
    # the copy followed the environment's world exactly: the references are of the same trajectory
    np.testing.assert_array_equal(d.qpos, u.data.qpos)
    return per_substep, end


def test_v0_reads_the_last_substep_and_v1_the_period_mean():
    e0 = _make("VSWrist/Polish-v0", config=CONFIG)
    e1 = _make("VSWrist/Polish-v1", config=CONFIG)
    u0, u1 = e0.unwrapped, e1.unwrapped
    assert (u0.tp["contact_force"], u1.tp["contact_force"]) == ("last_substep", "period_mean")
    assert (u0.task_id, u1.task_id) == ("VSWrist/Polish-v0", "VSWrist/Polish-v1")
    o0, _ = e0.reset(seed=5)
    o1, _ = e1.reset(seed=5)
    agent = AnalyticAgent(e1, stiffness=0.0)  # presses the tool on the surface and sweeps: the chatter case
    f0, f1, mean_ref, end_ref = [], [], [], []
    for _ in range(u1.episode_steps):
        a, _ = agent.predict(o1, deterministic=True)
        b0, b1 = copy.copy(u0.data), copy.copy(u1.data)
        o0, r0, term0, trunc0, i0 = e0.step(a)
        o1, r1, term1, trunc1, i1 = e1.step(a)
        # the same world under the same actions: the physics never depends on the reading
        np.testing.assert_array_equal(u0.data.qpos, u1.data.qpos)
        np.testing.assert_array_equal(u0.data.qvel, u1.data.qvel)
        per0, end0 = _touch_readings(u0, b0)
        per1, end1 = _touch_readings(u1, b1)
        assert per0 == per1 and end0 == end1
        f0.append(i0["contact_force"])
        f1.append(i1["contact_force"])
        mean_ref.append(float(np.mean(per1)))
        end_ref.append(end1)
        assert (term0, trunc0) == (term1, trunc1)
        if term1 or trunc1:
            break
    assert trunc1 and len(f1) == u1.episode_steps
    np.testing.assert_allclose(f0, end_ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(f1, mean_ref, rtol=1e-9, atol=1e-9)
    # the readings do differ: on pressed steps the end sample drops to 0 N where the period's mean does not
    pressed = np.asarray(mean_ref) > 1.0
    assert pressed.sum() > 50
    assert np.sum(np.asarray(end_ref)[pressed] == 0.0) >= 3
    # and everything the agent sees besides the force is the same
    sl = u1.obs_slices["contact_force"]
    keep = np.ones(o1.shape, dtype=bool)
    keep[sl] = False
    np.testing.assert_array_equal(o0[keep], o1[keep])


def test_contact_force_setting_is_validated_and_overrides_the_id():
    with pytest.raises(EnvConfigError) as exc:
        _make("VSWrist/Polish-v1", config={"task": {"contact_force": "mean"}})
    msg = str(exc.value)
    assert "task.contact_force" in msg and "period_mean" in msg and "last_substep" in msg and "\n" not in msg
    # the caller's settings apply over what the id fixes, and other task settings keep the id's reading
    u = _make("VSWrist/Polish-v0", config={"task": {"friction": 0.3}}).unwrapped
    assert (u.tp["contact_force"], u.tp["friction"]) == ("last_substep", 0.3)
    u = _make("VSWrist/Polish-v0", task={"friction": 0.3}).unwrapped
    assert u.tp["contact_force"] == "last_substep"
    u = _make("VSWrist/Polish-v1", config={"task": {"contact_force": "last_substep"}}).unwrapped
    assert u.task_id == "VSWrist/Polish-v0"  # the id whose reading it has


@pytest.mark.parametrize("env_id,reading", [("VSWrist/Polish-v0", "last_substep"),
                                            ("VSWrist/Polish-v1", "period_mean")])
def test_make_vec_builds_each_version(env_id, reading):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
    assert venv.env_id == env_id
    assert [e.tp["contact_force"] for e in venv.envs] == [reading] * 2
    single = _make(env_id)
    obs, _ = venv.reset(seed=4)
    o, _ = single.reset(seed=4)
    np.testing.assert_array_equal(obs[0], o)
    agent = AnalyticAgent(single, stiffness=0.0)
    forces = []
    for _ in range(40):
        a, _ = agent.predict(o, deterministic=True)
        obs, *_, info = venv.step(np.stack([a, a]))
        o, *_, i = single.step(a)
        assert info["contact_force"][0] == i["contact_force"]  # world 0 is gym.make(env_id) with the seed
        forces.append(i["contact_force"])
    assert max(forces) > 1.0  # the tool is pressed: the reading was exercised
    venv.close()


def test_a_policy_of_one_version_is_refused_on_the_other():
    """The shipped Polish policy was trained with the period-mean force (v1): on v0 it is a one-line error
    naming the id to use, on `--task Polish` (the newest) it runs."""
    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.runs import RunDirError

    spec = AgentSpec("pretrained:Polish")
    spec.check_task(vswrist_gym.resolve_id("Polish"))
    with pytest.raises(RunDirError) as exc:
        spec.check_task("VSWrist/Polish-v0")
    assert "give --task VSWrist/Polish-v1" in str(exc.value) and "\n" not in str(exc.value)
