"""VSWrist/Hammer-v0: the swing runs the motors at their speed limit, the strike speed is the head's speed just
before contact, a stiff wrist strikes near the rigid bound while springs let the head outrun it, success is out of
reach of flailing, and a stiffness schedule beats every constant stiffness."""

from __future__ import annotations

import gymnasium as gym
import mujoco
import numpy as np
import pytest

import vswrist_gym  # noqa: F401
from conftest import final_info as _episode
from vswrist_gym.tools.probe import (CONSTANT_COMMANDS, adaptive_policy, constant_policy, evaluate, probe,
                                    random_policy)

ID = "VSWrist/Hammer-v0"


def test_swing_runs_the_fastest_motor_at_its_speed_limit():
    """Along the reference, the leg angles (exact inverse kinematics) change at most at the speed limit, and the
    fastest one at it, through the swing (the ramp is integrated in FE; this differentiates in time)."""
    env = gym.make(ID)
    u = env.unwrapped
    env.reset(seed=4)
    from vswrist_gym.kinematics import WristKinematics

    kin = WristKinematics(u.nominal_params)
    vmax = u.nominal_params.motor.speed_limit
    t0 = u.tp["swing_start_s"]
    h = 1e-4
    rates = []
    for t in np.linspace(t0 + 0.01, t0 + 0.08, 8):
        qa = kin.joint_angles(u._reference(t + h)[:2])[0::4]
        qb = kin.joint_angles(u._reference(t - h)[:2])[0::4]
        rates.append(np.max(np.abs(qa - qb)) / (2 * h))
    np.testing.assert_allclose(rates, vmax, rtol=0.01)
    assert u._reference(t0 - 0.01)[1] == u.tp["fe_start"]


def test_v1_winds_up_then_swings_with_the_fastest_motor_at_its_speed_limit():
    """Hammer-v1's reference: from fe_start back to fe_back and forward through the anvil, the fastest leg's
    angle (exact inverse kinematics, differentiated in time) at windup_speed x the speed limit going back and at
    swing_speed x it going forward; the strike deadline counts from the turn, not from the wind-up's start."""
    env = gym.make("VSWrist/Hammer-v1")
    u = env.unwrapped
    env.reset(seed=4)
    tp = u.tp
    assert tp["fe_back"] < tp["fe_start"] < tp["fe_strike"][0]
    from vswrist_gym.kinematics import WristKinematics

    kin = WristKinematics(u.nominal_params)
    vmax = u.nominal_params.motor.speed_limit
    t_turn = u._swing_t0
    assert u._reference(t_turn)[1] == pytest.approx(tp["fe_back"], abs=1e-12)
    assert tp["swing_start_s"] + 0.02 < t_turn  # the wind-up took time
    h = 1e-4

    def top_rate(t):
        qa = kin.joint_angles(u._reference(t + h)[:2])[0::4]
        qb = kin.joint_angles(u._reference(t - h)[:2])[0::4]
        return np.max(np.abs(qa - qb)) / (2 * h)

    back = [top_rate(t) for t in np.linspace(tp["swing_start_s"] + 0.01, t_turn - 0.01, 5)]
    fwd = [top_rate(t) for t in np.linspace(t_turn + 0.01, t_turn + 0.08, 5)]
    np.testing.assert_allclose(back, tp["windup_speed"] * vmax, rtol=0.01)
    np.testing.assert_allclose(fwd, tp["swing_speed"] * vmax, rtol=0.01)
    # FE falls through the wind-up and rises after the turn
    assert u._reference(t_turn - 0.02)[1] < tp["fe_start"] and u._reference(t_turn + 0.02)[1] > tp["fe_back"]
    assert not u.timely()  # no strike yet

    def strike_at(t):  # a first contact whose substep starts t s into the episode
        u._ep.task.put(0, struck=False)
        u._on_first_contact(u._t0 + t + u.sim.timestep, u._face.copy(), np.zeros(3))
        return u.timely()

    assert strike_at(t_turn + tp["strike_deadline_s"] - 1e-6)
    assert not strike_at(t_turn + tp["strike_deadline_s"] + 1e-6)


def test_leg_rate_matches_finite_differences_of_the_inverse_kinematics():
    """The leg rate (the controller's closed-form J_a, FE column) = |d q1 / d FE| by central differences of the
    exact inverse kinematics (``WristKinematics.joint_angles``, least-squares-free; a second derivation). The
    difference step 1e-5 rad leaves a truncation error ~1e-10 relative, far inside the bound."""
    from vswrist_gym.kinematics import WristKinematics

    env = gym.make(ID)
    u = env.unwrapped
    env.reset(seed=1)
    kin = WristKinematics(u.nominal_params)
    h = 1e-5
    for fe in (-0.6, 0.0, 0.6, 0.9):
        qa = kin.joint_angles(np.array([u._rud, fe + h]))[0::4]
        qb = kin.joint_angles(np.array([u._rud, fe - h]))[0::4]
        assert u._leg_rate(fe) == pytest.approx(np.max(np.abs(qa - qb)) / (2 * h), rel=1e-8)


def test_strike_speed_is_the_head_speed_just_before_contact():
    """The strike speed reported = the head's displacement along the anvil normal over the substep before the
    contact, divided by the substep (positions recorded independently of the velocity the env reads)."""
    env = gym.make(ID)
    u = env.unwrapped
    env.reset(seed=2)
    step, rec = u.sim.step, []
    m = u.model
    d2 = mujoco.MjData(m)

    def recording_step(duration, restart_peak=True):
        # the period replayed on a copy of the world one substep at a time, the head's pose at each substep's start
        mujoco.mj_copyData(d2, m, u.data)
        for _ in range(int(round(duration / m.opt.timestep))):
            mujoco.mj_kinematics(m, d2)
            rec.append((d2.time, float(d2.xpos[u._head_body] @ u._normal)))
            mujoco.mj_step(m, d2, 1)
        step(duration, restart_peak)
    u.sim.step = recording_step
    info = _episode(env, constant_policy(env, -0.5), 2)
    assert info["struck"]
    t_abs = info["impact_time"] + u._t0
    times = np.array([t for t, _ in rec])
    k = int(np.argmin(np.abs(times - t_abs)))
    assert abs(times[k] - t_abs) < 1e-9
    v_fd = (rec[k][1] - rec[k - 1][1]) / u.sim.timestep
    assert info["impact_speed"] == pytest.approx(v_fd, rel=0.03)


def test_stiff_wrist_strikes_near_the_rigid_bound_and_springs_outrun_it():
    """Full stiffness: within -15 %/+30 % of the rigid bound (the coupler's highest stiffness still lets the head
    swing about 1/8 of a period past the motors; measured 0.93-1.18 on 6 episodes); a soft wrist outruns it by more
    than 30 % (1.6-1.8 measured): the springs store and return energy."""
    env = gym.make(ID)
    for seed in (1, 2, 3):
        stiff = _episode(env, constant_policy(env, 1.0), seed)
        soft = _episode(env, constant_policy(env, -0.5), seed)
        assert 0.85 < stiff["impact_speed"] / stiff["rigid_speed"] < 1.3
        assert soft["impact_speed"] / soft["rigid_speed"] > 1.3


def test_flailing_does_not_succeed():
    """Random and bang-bang actions, in the default mode (posture and stiffness) and the residual mode (the
    swing dithered), succeed in none of the episodes; the hand-written rule does. Over 20 episodes each (seeds
    1000-1019) flailing struck in time, on the nail, at most at 1.64 x the rigid bound (the success ratio is 1.75;
    the rule reached 1.88-1.96 on 12 episodes)."""
    for mode in ("posture_stiffness", "residual"):
        env = gym.make(ID, config={"action_mode": mode})
        for bang in (False, True):
            rng = np.random.default_rng(0)
            assert evaluate(env, lambda b=bang: random_policy(env, rng, b), range(1000, 1006))[1] == 0.0, (mode, bang)
    env = gym.make(ID)
    assert evaluate(env, lambda: adaptive_policy(env), range(1000, 1003))[1] > 0.0


def test_rule_beats_every_constant_on_hammer():
    """Headroom: the rule (soft before the swing, full stiffness from its start) beats every constant stiffness
    command on held-out episodes, and on each of them beats the best constant's strike speed."""
    r = probe("Hammer", episodes=4, seed0=1000, oracle=False)
    assert r["adaptive"][0] > max(v[0] for v in r["constant"].values())
    best = f"s={r['best_constant']:+.1f}"
    assert np.all(np.array(r["impact_speed"]["rule"]) > np.array(r["impact_speed"][best]))


@pytest.mark.slow
def test_optimised_schedule_beats_every_constant_on_held_out_episodes():
    """The open-loop schedule optimised on training seeds (100-105) beats every constant on held-out ones."""
    r = probe("Hammer", episodes=8, seed0=1000)
    assert r["oracle"][0] > max(v[0] for v in r["constant"].values())
    assert len(CONSTANT_COMMANDS) == len(r["constant"])


def test_evaluate_records_the_strike_speed_of_the_last_step():
    """`vswrist evaluate`'s records carry Hammer's impact speed: the last step's info of the same episodes run
    directly (a second path: gym.make, the analytic agent, the protocol's reset seeds), and NaN on a task without
    it; the comparison table shows the column only where a row reports it."""
    from vswrist_gym.agents.analytic import AnalyticAgent
    from vswrist_gym.agents.compare import table_markdown
    from vswrist_gym.agents.protocol import evaluate as protocol_evaluate
    from vswrist_gym.agents.protocol import reset_seed, summarise

    records, _ = protocol_evaluate(ID, lambda e: AnalyticAgent(e, stiffness=-0.5), seeds=[0], episodes=2)
    env = gym.make(ID)
    agent = AnalyticAgent(env, stiffness=-0.5)
    for k, rec in enumerate(records):
        obs, info = env.reset(seed=reset_seed(0, k))
        done = False
        while not done:
            obs, _, term, trunc, info = env.step(agent.predict(obs, deterministic=True)[0])
            done = term or trunc
        assert info["struck"] and rec["impact_speed"] == pytest.approx(info["impact_speed"], rel=1e-9)
        assert rec["impact_speed"] > info["rigid_speed"]  # springs outrun the rigid bound at s = -0.5
    other, _ = protocol_evaluate("VSWrist/LoadHold-v0", lambda e: AnalyticAgent(e), seeds=[0], episodes=1)
    assert np.isnan(other[0]["impact_speed"])
    assert "impact_speed" in table_markdown([("a", summarise(records))])
    assert "impact_speed" not in table_markdown([("a", summarise(other))])


@pytest.mark.parametrize("env_id", ["VSWrist/Hammer-v0", "VSWrist/Hammer-v1", "VSWrist/Throw-v0"])
def test_swings_integrated_over_arrays_are_the_scalar_swings_to_the_bit(env_id):
    """A batch whose worlds reset together integrates their swing ramps over arrays (``ramp.ramp_references``,
    ``ramp_through_worlds``); each world's ramp must be what the single env integrates alone with the same seed,
    point for point, and what the one-world integration (``ramp_reference``, ``ramp_through``) gives with the
    task's scalar rate: the batch's worlds and ``gym.make`` replay the same episodes only then. Identical to the bit
    on the dev machine; the bound is 1e-12 rad because NumPy's sin/cos may differ from math's in the last bit on
    other CPUs (SIMD builds), and one-ulp differences in the rate, summed over the ramp's ~100-600 points of 1 ms,
    stay below 1e-13 rad (a margin of 10, as tests/test_control.py allows the controller's array path). The times
    are sums of dt in either form, so they must agree exactly (a turn's hold starts where the first leg ends)."""
    from vswrist_gym.envs import ramp

    n = ramp.RAMP_ARRAY_MIN_WORLDS + 3
    v = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", threads=1)
    v.reset(seed=40)
    worlds = v.unwrapped.envs
    assert len({e._rud for e in worlds}) == n  # distinct swings
    throw = env_id.startswith("VSWrist/Throw")
    for i, e in enumerate(worlds):
        alone = gym.make(env_id).unwrapped
        alone.reset(seed=40 + i)
        assert alone._rud == e._rud
        tp = alone.tp
        if throw:
            limit = alone.nominal_params.motor.speed_limit
            rates = tuple(ramp.fe_rate(alone.ctrl, alone._rud, tp[k] * limit) for k in ("windup_speed", "swing_speed"))
            want = ramp.ramp_through((tp["fe_start"], tp["fe_back"], tp["fe_end"]), rates, tp["windup_start_s"],
                                     tp["windup_hold_s"], alone.cfg["episode_s"])
            got = ((e._ref_t, e._ref_fe), (alone._ref_t, alone._ref_fe))
        elif alone.windup:
            rates = (lambda fe: alone._fe_rate(fe, tp["windup_speed"]), alone._fe_rate)
            want = ramp.ramp_through((tp["fe_start"], tp["fe_back"], tp["fe_end"]), rates, tp["swing_start_s"],
                                     tp["windup_hold_s"], alone.cfg["episode_s"])
            got = ((e._swing_t, e._swing_fe), (alone._swing_t, alone._swing_fe))
        else:
            want = ramp.ramp_reference(tp["fe_start"], tp["fe_end"], alone._fe_rate, tp["swing_start_s"],
                                       alone.cfg["episode_s"])
            got = ((e._swing_t, e._swing_fe), (alone._swing_t, alone._swing_fe))
        if throw or alone.windup:
            assert want[1].min() < tp["fe_start"]  # the wind-up turns back before the swing
        for ts, fes in got:
            assert ts.shape == want[0].shape and np.array_equal(ts, want[0])
            np.testing.assert_allclose(fes, want[1], rtol=0, atol=1e-12)
        assert e._ep.task.swing_t0[0] == alone._ep.task.swing_t0[0]
        alone.close()
    v.close()


def test_ramps_over_arrays_stop_where_each_ramp_stops_alone():
    """``ramp_references`` with a start and an end of its own for each ramp: a ramp cut by its episode's end stops
    where the one-world loop stops, and one that reaches its target first holds it, each to the bit (a constant
    rate: the same additions either way)."""
    from vswrist_gym.envs import ramp

    starts, ends = np.array([0.05, 0.05, 0.2]), np.array([0.3, 2.0, 0.5])
    ramps = ramp.ramp_references(-0.75, 0.95, lambda fe, rows: np.full(len(rows), 1.0), 3, starts, ends)
    for (ts, fes), t0, t1 in zip(ramps, starts, ends):
        alone = ramp.ramp_reference(-0.75, 0.95, lambda fe: 1.0, t0, t1)
        assert np.array_equal(ts, alone[0]) and np.array_equal(fes, alone[1])
    assert ramps[0][1][-1] < 0.95 and ramps[1][1][-1] == 0.95  # cut short; reached


def test_off_plane_error_is_the_running_maximum_up_to_the_strike():
    """The success's off-plane error, read from the episode's error history: what a running maximum of the RUD and PS
    errors from 0 (Python's max, which skips a NaN error) reaches by the strike's step, or by the last step without
    a strike."""
    from vswrist_gym.envs import hammer

    rng = np.random.default_rng(0)
    err = rng.normal(0.0, 0.1, (3, 12, 3))
    err[1, 4, 0] = np.nan
    err[2, :, 2] = np.nan
    strike_step = np.array([0, 7, 12])
    for e, k, got in zip(err, strike_step, hammer.off_plane_errors(err, strike_step)):
        running = 0.0
        for row in e[:k or len(e)]:
            running = max(running, abs(float(row[0])), abs(float(row[2])))
        assert got == running
