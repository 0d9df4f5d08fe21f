"""The per-substep contact measurements of Polish and Hammer (``envs.shared.PeriodMeanForce``): the compiled
``vswrist.contact`` plugin, which measures inside one ``mj_step(m, d, n)`` per control period, against an
independent per-substep reading from Python, against the Python fallback's own loop, and its errors."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import vswrist_gym
from vswrist_gym.model import native

try:
    native.load_plugin()
except RuntimeError as exc:  # no C compiler: only the fallback exists
    pytest.skip(f"the compiled plugin is unavailable: {exc}", allow_module_level=True)


def _replay_substeps(u, pair):
    """Wrap ``u.sim.step`` so that, before each control period, a copy of the world is advanced one substep at a
    time: ``mj_forward`` (the state the substep starts from: its contacts and solved forces), then the reading,
    then ``mj_step(m, d, 1)``. Per period it records (mean normal force over the substeps of the contacts of
    ``pair``, the first such substep's start time, the meter body's linear velocity there from its Jacobian).
    ``pair``: (geom a, geom b or -1 for anything); the body: Hammer's head."""
    m, step = u.model, u.sim.step
    body = int(m.body("hammer_head" if u.task == "hammer" else "task_surface").id)
    d2 = mujoco.MjData(m)
    jacp = np.zeros((3, m.nv))
    f = np.zeros(6)
    rec = []

    def replaying_step(duration, restart_peak=True):
        assert restart_peak, "latency is off: one physics call per control period"
        mujoco.mj_copyData(d2, m, u.data)
        total, n, first = 0.0, 0, None
        for _ in range(int(round(duration / m.opt.timestep))):
            mujoco.mj_forward(m, d2)
            for i in range(d2.ncon):
                g = set(d2.contact[i].geom)
                if pair[0] in g and (pair[1] < 0 or pair[1] in g):
                    if first is None:
                        mujoco.mj_jacBodyCom(m, d2, jacp, None, body)
                        first = (float(d2.time), jacp @ d2.qvel)
                    mujoco.mj_contactForce(m, d2, i, f)
                    total += f[0]
            n += 1
            mujoco.mj_step(m, d2, 1)
        rec.append((total / n, first))
        step(duration, restart_peak)

    u.sim.step = replaying_step
    return rec


@pytest.mark.parametrize("task", ["Polish", "Hammer"])
def test_compiled_meter_equals_a_per_substep_reading_from_python(task):
    """The plugin's period mean (``info['contact_force']``) and Hammer's strike (time, normal speed) equal a
    reading taken substep by substep on a copy of the world, with mj_forward before each substep and the head's
    velocity from its Jacobian (not mj_objectVelocity), on a short episode with contact."""
    env = gym.make(vswrist_gym.resolve_id(task), config={"randomize": {"latency": {"enabled": False}}})
    u = env.unwrapped
    assert u._meter is not None, "the compiled physics should carry the vswrist.contact instance"
    env.reset(seed=5)
    geom = lambda name: int(u.model.geom(name).id)  # noqa: E731
    pair = (geom("task_task_surface_0"), -1) if task == "Polish" else (geom("task_head"), geom("task_task_anvil_0"))
    rec = _replay_substeps(u, pair)
    forces, touched = [], 0
    strike_seen = None
    for k in range(40):
        _, _, term, trunc, info = env.step(u.reference_to_action(u._target, 0.5))
        mean, first = rec[-1]
        forces.append(info["contact_force"])
        assert info["contact_force"] == pytest.approx(mean, rel=1e-9, abs=1e-9), f"step {k}"
        touched += first is not None
        if task == "Hammer" and first is not None and strike_seen is None:
            strike_seen = first
            t0, v = first
            assert info["struck"]
            assert info["impact_time"] == pytest.approx(t0 - u._t0, abs=1e-9)
            assert info["impact_speed"] == pytest.approx(float(v @ u._normal), rel=1e-9, abs=1e-9)
        if term or trunc:
            break
    assert touched >= 5 and max(forces) > 1.0, "the episode must press/strike for the test to mean anything"
    if task == "Hammer":
        assert strike_seen is not None


@pytest.mark.parametrize("task", ["Polish", "Hammer"])
def test_compiled_meter_reproduces_the_python_fallback(task, monkeypatch):
    """The same episode (random actions, latency randomisation on, so a period is split in two physics calls)
    with the compiled plugin and with the Python fallback (no plugin: one substep at a time, read from Python):
    rewards and the contact/strike info agree to rounding (1e-9), observations to float32 rounding."""
    cfg = {"episode_s": 0.3, "randomize": {"latency": {"enabled": True}}}
    keys = ["contact_force", "peak_contact_force", "rms_contact_force"]
    keys += ["struck", "impact_speed", "impact_time", "impact_offset"] if task == "Hammer" else []
    runs = []
    for backend in ("1", "0"):
        monkeypatch.setenv("VSWRIST_NATIVE", backend)
        try:
            # Hammer-v0: random postures strike its anvil within 0.3 s; v1's wind-up first swings away from it
            env = gym.make("VSWrist/Hammer-v0" if task == "Hammer" else vswrist_gym.resolve_id(task), config=cfg)
            assert (env.unwrapped._meter is None) == (backend == "0")
            rng = np.random.default_rng(7)
            obs, _ = env.reset(seed=7)
            rows = []
            for _ in range(35):
                obs, r, term, trunc, info = env.step(rng.uniform(-1, 1, 4).astype(np.float32))
                rows.append(np.concatenate([obs, [r, term, trunc], [float(info[k]) for k in keys]]))
                if term or trunc:
                    obs, _ = env.reset()
            runs.append(np.array(rows))
            env.close()
        finally:
            monkeypatch.delenv("VSWRIST_NATIVE")
            native.install("c")
    n_obs = runs[0].shape[1] - 3 - len(keys)
    # observations are float32: the two backends' rounding-level differences may flip their last bit
    np.testing.assert_allclose(runs[0][:, :n_obs], runs[1][:, :n_obs], rtol=2e-7, atol=1e-7)
    np.testing.assert_allclose(runs[0][:, n_obs:], runs[1][:, n_obs:], rtol=0, atol=1e-9)
    assert np.max(runs[0][:, -len(keys)]) > 0.0  # some contact happened


def test_contact_meter_config_errors_name_the_instance():
    from vswrist_gym.model.builder import build_spec
    from vswrist_gym.model.plugin_lib import CONTACT_PLUGIN

    for config, match in (({"geom1": "no_such_geom"}, "config geom1 must name a geom"),
                          ({"geom1": "hand_palm", "geom2": "nope"}, "config geom1 must name a geom"),
                          ({}, "config geom1 must name a geom")):
        spec = build_spec(physics="plugin")
        spec.activate_plugin(CONTACT_PLUGIN)
        inst = spec.add_plugin(name="meter", plugin_name=CONTACT_PLUGIN, active=True)
        inst.config = config
        spec.body("tool").plugin.name = "meter"
        spec.body("tool").plugin.active = True
        with pytest.raises(ValueError, match=f"vswrist.contact instance 'meter': {match}"):
            spec.compile()


def test_contact_meter_state_survives_get_and_set_state_and_is_per_mjdata():
    """The measurements live in plugin_state: a state saved mid-period and restored into a fresh world gives the
    same period mean (mjSTATE_INTEGRATION includes mjSTATE_PLUGIN), and another MjData of the same model keeps
    its own accumulator."""
    env = gym.make("VSWrist/Polish-v1")
    u = env.unwrapped
    env.reset(seed=2)
    for _ in range(20):
        env.step(u.reference_to_action(u._target, 0.5))
    u._meter[:] = 0.0
    u.sim.step(5 * u.model.opt.timestep)
    saved, half = u.sim.get_state(), u._meter.copy()
    assert half[1] == 5 and half[0] > 0.0
    adr = int(u.model.plugin_stateadr[mujoco.mj_name2id(u.model, mujoco.mjtObj.mjOBJ_PLUGIN, "contact_meter")])
    other = mujoco.MjData(u.model)
    np.testing.assert_array_equal(other.plugin_state[adr:adr + len(half)], 0.0)
    u.sim.step(5 * u.model.opt.timestep)
    full = u._meter.copy()
    u._meter[:] = 0.0
    u.sim.set_state(saved)
    np.testing.assert_array_equal(u._meter, half)
    u.sim.step(5 * u.model.opt.timestep)
    np.testing.assert_array_equal(u._meter, full)
