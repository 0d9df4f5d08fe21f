"""The compiled advance (``model.advance_lib``): an error MuJoCo raises inside one world is reported for that
world, on the calling thread and on the library's pool, where the bindings' ``mj_step`` raises FatalError;
the process lives on and the other worlds step. (Its numbers against ``WristSim`` are ``test_batch.py``'s.)"""

import mujoco
import numpy as np
import pytest

from vswrist_gym.model import advance_lib

LIB = advance_lib.load()
pytestmark = pytest.mark.skipif(LIB is None, reason="no C++ compiler: the batch steps world by world")


def _crowded(memory: int) -> str:
    """20 overlapping free spheres: the first step's contacts need more arena than ``memory`` bytes. One
    motor, the ctrl the call writes (its 4 references all go to ctrl[0])."""
    bodies = "".join(f'<body pos="0 0 {0.05 * i}"><freejoint/><geom size="0.1"/></body>' for i in range(20))
    motor = '<body pos="3 0 0"><joint name="h"/><geom size="0.05"/></body>'
    return (f'<mujoco><size memory="{memory}"/><worldbody>{bodies}{motor}</worldbody>'
            f'<actuator><motor joint="h"/></actuator></mujoco>')


def _failing_model() -> mujoco.MjModel:
    """A model that compiles but whose mj_step raises (a stack overflow): the smallest arena that compiles.
    Searched rather than fixed, since the arena a model needs depends on the MuJoCo build."""
    for memory in range(10_000, 40_000, 250):
        try:
            m = mujoco.MjModel.from_xml_string(_crowded(memory))
        except ValueError:
            continue
        try:
            mujoco.mj_step(m, mujoco.MjData(m), 5)
        except mujoco.FatalError:
            return m
    pytest.skip("no arena size makes this MuJoCo build raise inside mj_step")


def _table(model, datas, peaks) -> np.ndarray:
    h = np.zeros((len(datas), advance_lib.HANDLE_COLUMNS), dtype=np.uint64)
    for row, d, p in zip(h, datas, peaks):
        row[advance_lib.H_MODEL], row[advance_lib.H_DATA], row[advance_lib.H_PEAK] = model._address, d._address, \
            p.ctypes.data
    return h


def test_a_mujoco_error_is_reported_for_its_world_and_the_others_step():
    bad = _failing_model()
    good = mujoco.MjModel.from_xml_string(_crowded(1_000_000))
    datas = [mujoco.MjData(bad), mujoco.MjData(good)]
    peaks = [np.ones(1), np.ones(1)]
    h = np.vstack([_table(bad, datas[:1], peaks[:1]), _table(good, datas[1:], peaks[1:])])
    status = np.full(2, -1, dtype=np.int32)
    theta, ctrl_idx = np.full((2, 4), 0.5), np.zeros(4, dtype=np.int32)
    # on the calling thread
    nbad = advance_lib.advance(LIB, h, np.array([0, 1], dtype=np.int32), theta, ctrl_idx, 5, 0, status)
    assert nbad == 1 and status.tolist() == [advance_lib.MUJOCO_ERROR, advance_lib.OK]
    assert datas[1].time == pytest.approx(5 * good.opt.timestep)  # the good world ran its 5 substeps
    assert peaks[1][0] == 0.0  # the closure peak restarts with the period
    assert datas[1].ctrl[0] == 0.5  # the motor references are written before the substeps
    # on the pool: one world per chunk, so each runs on a pool thread
    pool = advance_lib.Pool(LIB, 2)
    try:
        status[:] = -1
        pool.submit(h, np.array([0, 1], dtype=np.int32), theta, ctrl_idx, 5, 0, status, None,
                    np.array([0, 1, 2], dtype=np.int32))
        pool.wait()
    finally:
        pool.close()
    assert status.tolist() == [advance_lib.MUJOCO_ERROR, advance_lib.OK]
    assert datas[1].time == pytest.approx(10 * good.opt.timestep)


def test_the_pool_runs_only_released_chunks_and_leaves_kept_ones():
    """``submit(..., released=1)`` lets one chunk run; ``run_one(keep)`` claims none while at most ``keep`` are
    left unclaimed; ``release()`` lets the rest run; ``wait()`` waits for every released chunk."""
    good = mujoco.MjModel.from_xml_string(_crowded(1_000_000))
    datas = [mujoco.MjData(good) for _ in range(3)]
    peaks = [np.ones(1) for _ in range(3)]
    h = _table(good, datas, peaks)
    status = np.full(3, -1, dtype=np.int32)
    theta, ctrl_idx = np.full((3, 4), 0.5), np.zeros(4, dtype=np.int32)
    bounds = np.array([0, 1, 2, 3], dtype=np.int32)
    pool = advance_lib.Pool(LIB, 1)
    try:
        pool.submit(h, np.arange(3, dtype=np.int32), theta, ctrl_idx, 2, 0, status, None, bounds, released=1)
        pool.wait()
        assert pool.ready().tolist() == [True, False, False]
        assert status.tolist() == [advance_lib.OK, -1, -1] and datas[1].time == 0.0
        assert pool.run_one() == -1  # chunks 1 and 2 are not released
        pool.release()
        assert pool.run_one(keep=1) in (-1, 1, 2)  # the pool thread may have claimed some already
        assert pool.run_one(keep=2) == -1  # at most two are left unclaimed now
        pool.wait()
        assert pool.ready().all() and status.tolist() == [advance_lib.OK] * 3
        assert all(d.time == pytest.approx(2 * good.opt.timestep) for d in datas)
    finally:
        pool.close()


def test_the_gather_copies_what_its_plan_names_from_each_world():
    """The gather (``plan``/``out``): after the substeps, world k's row of ``out`` holds the named slices of its
    MjData and its closure peak, in plan order; a world whose step failed is left unwritten. Checked against the
    MjData arrays read through the bindings."""
    bad = _failing_model()
    good = mujoco.MjModel.from_xml_string(_crowded(1_000_000))
    datas = [mujoco.MjData(good), mujoco.MjData(bad), mujoco.MjData(good)]
    peaks = [np.ones(1), np.ones(1), np.ones(1)]
    h = np.vstack([_table(good, datas[:1], peaks[:1]), _table(bad, datas[1:2], peaks[1:2]),
                   _table(good, datas[2:], peaks[2:])])
    datas[2].qvel[2] = 0.3  # the two good worlds differ
    A = advance_lib
    plan = np.array([(A.F_QPOS, 7, 7), (A.F_QVEL, 2, 3), (A.F_XPOS, 3 * 4, 3), (A.F_XQUAT, 4 * 2, 4),
                     (A.F_XMAT, 9 * 3, 9), (A.F_CVEL, 6 * 5, 6), (A.F_PEAK, 0, 1)], dtype=np.int32)
    out = np.full((3, int(plan[:, 2].sum())), -7.0)
    status = np.full(3, -1, dtype=np.int32)
    A.advance(LIB, h, np.array([0, 1, 2], dtype=np.int32), np.zeros((3, 4)), np.zeros(4, dtype=np.int32), 3,
              A.SYNC_KINEMATICS, status, None, plan, out)
    assert status.tolist() == [A.OK, A.MUJOCO_ERROR, A.OK]
    for k in (0, 2):
        d = datas[k]
        want = np.concatenate([d.qpos[7:14], d.qvel[2:5], d.xpos[4], d.xquat[2], d.xmat[3], d.cvel[5], peaks[k]])
        np.testing.assert_array_equal(out[k], want)
    assert not np.array_equal(out[0], out[2])
    assert (out[1] == -7.0).all()
