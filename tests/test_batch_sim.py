"""``batch_sim.BatchSim`` (the compiled advance over many simulators, and its reads over arrays) against the
single simulator: each world's period and reads must be what ``WristSim.step`` and its accessors give a twin
simulator driven the same way."""

import numpy as np
import pytest

from vswrist_gym.batch_sim import OK, BatchSim
from vswrist_gym.sim import WristSim

CTRL_DT = 0.02
POSTURES = [((0.1, -0.2), 0.3, 1.0), ((-0.15, 0.25), -0.2, 3.0), ((0.0, 0.05), 0.0, 0.5)]
THETA = np.array([[0.05, -0.03, 0.02, 0.3], [-0.1, 0.08, 0.04, -0.25], [0.0, 0.01, -0.02, 0.05]])


def _worlds():
    sims = []
    for u, ps, lam in POSTURES:
        s = WristSim("paper")
        s.reset(u=u, ps=ps, lam=lam)
        s.apply_wrench((0.5, -1.0, 2.0), (0.01, 0.0, -0.02))  # a load, so that the springs deflect and sensors read
        sims.append(s)
    if sims[0].backend != "c":
        pytest.skip("no compiled plugin (no C compiler)")
    return sims


@pytest.mark.parametrize("light", [False, True], ids=["forward", "kinematics"])
def test_a_period_and_its_reads_are_the_single_simulators(light):
    batch, twins = _worlds(), _worlds()
    bsim = BatchSim(len(batch), batch[0], CTRL_DT, light=light, tool_wrench=not light, meter=False)
    if bsim.lib is None:
        pytest.skip("no C++ compiler")
    for i, s in enumerate(batch):
        bsim.attach(i, s, CTRL_DT)
    worlds = np.arange(len(batch), dtype=np.int32)
    for period in range(3):
        status = np.full(len(batch), -1, dtype=np.int32)
        G = np.empty((len(batch), bsim.width))
        assert bsim.advance(worlds, THETA * (period + 1), status, out=G) == 0
        assert bsim.settle(batch, status) == [OK] * len(batch)
        for s, th in zip(twins, THETA * (period + 1)):
            s.set_motor_references(th)
            s.step(CTRL_DT)
            s.sync_kinematics() if light else s.sync()
        P, D, Q = bsim.read_posture(G)
        want = {
            "posture": np.array([s.posture() for s in twins]),
            "deflections": np.array([s.deflections() for s in twins]),
            "posture_rate": np.array([s.posture_rate() for s in twins]),
            "motor_angles": np.array([s.motor_angles() for s in twins]),
            "closure": np.array([s.loop_closure_peak() for s in twins]),
        }
        got = {"posture": P, "deflections": D, "posture_rate": bsim.read_posture_rate(G, P),
               "motor_angles": bsim.read_motor_angles(Q), "closure": np.array(bsim.read_closure(G, batch))}
        if not light:
            want["tool_wrench"] = np.array([s.tool_wrench() for s in twins])
            got["tool_wrench"] = bsim.read_tool_wrench(G)
        for k in want:
            np.testing.assert_allclose(got[k], want[k], rtol=0, atol=1e-12, err_msg=f"period {period} {k}")
        assert np.abs(want["deflections"]).max() > 1e-4  # the springs carry load: the comparison means something
        np.testing.assert_array_equal(bsim.gather(batch), G)  # the Python gather reads what the call copied


def test_latency_runs_its_substeps_on_the_previous_references():
    """With k substeps of latency the period is k substeps on the motor references already in place, then the
    new ones for the rest, the loop-closure peak over the whole period (``VSWristEnv._advance``'s two calls)."""
    batch, twins = _worlds(), _worlds()
    bsim = BatchSim(len(batch), batch[0], CTRL_DT, light=False, tool_wrench=False, meter=False)
    if bsim.lib is None:
        pytest.skip("no C++ compiler")
    for i, s in enumerate(batch):
        bsim.attach(i, s, CTRL_DT)
    worlds = np.arange(len(batch), dtype=np.int32)
    dt = batch[0].timestep
    lat = [0, 3, 19]  # substeps; a period is 20
    status = np.zeros(len(batch), dtype=np.int32)
    bsim.advance(worlds, THETA, status)  # the references of the first period, without latency
    bsim.set_latency(list(range(len(batch))), lat)
    bsim.advance(worlds, 2 * THETA, status)
    bsim.settle(batch, status)
    for s, k, th in zip(twins, lat, THETA):
        s.set_motor_references(th)
        s.step(CTRL_DT)
        if k:
            s.step(k * dt)
            s.set_motor_references(2 * th)
            s.step(CTRL_DT - k * dt, restart_peak=False)
        else:
            s.set_motor_references(2 * th)
            s.step(CTRL_DT)
        s.sync()
    for s, t in zip(batch, twins):
        np.testing.assert_array_equal(s.data.qpos, t.data.qpos)
        np.testing.assert_array_equal(s.data.qvel, t.data.qvel)
        assert s.loop_closure_peak() == t.loop_closure_peak()
    # and latency changes the outcome: world 1 without it ends elsewhere
    plain = _worlds()[1]
    for th in (THETA[1], 2 * THETA[1]):
        plain.set_motor_references(th)
        plain.step(CTRL_DT)
    assert not np.array_equal(plain.data.qpos, batch[1].data.qpos)
