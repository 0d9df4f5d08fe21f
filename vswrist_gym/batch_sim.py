"""Many simulators (``WristSim``) as one: one control period of a batch's worlds through the compiled advance
(``model.advance_lib``: one GIL-free C++ call per chunk of worlds, or its thread pool), and what the batch reads
of them after the period, gathered into one (N, .) array and computed over arrays.

Why a class of its own: the batched environment (``envs.batch``) needs the physics of many worlds at once, the
raw MuJoCo addresses of their models and data, and the simulators' internal layout (joint addresses, the
loop-closure bodies, the tool's sensors). Those belong to the simulator layer; the environment steps and reads
through this interface only.

The reads compute what ``WristSim.posture``/``deflections``/``posture_rate``/``loop_closure_peak``/
``tool_wrench`` compute, through the same functions (``sim.posture_rate_terms``, ``sim.tool_wrench_of``,
``native.weld_opening``) over arrays of worlds, and the coupler's angles (``sim.coupler_angles``) world by world in
the gather (in C, with the same C library functions, by the compiled advance), so that world i of a batch is the
single env on one machine.
"""

from __future__ import annotations

import os

import numpy as np

from .model import advance_lib as A
from .model.native import weld_opening
from .sim import WristSim, coupler_angles, posture_rate_terms, tool_wrench_of

OK, DIVERGED, MUJOCO_ERROR = A.OK, A.DIVERGED, A.MUJOCO_ERROR  # a world's status after a period

# the MjData array behind each field of a gather plan (``advance_lib.F_*``), for ``BatchSim.gather``
GATHER_FIELDS = {A.F_QPOS: "qpos", A.F_QVEL: "qvel", A.F_XPOS: "xpos", A.F_XQUAT: "xquat", A.F_XMAT: "xmat",
                 A.F_CVEL: "cvel", A.F_SENSOR: "sensordata", A.F_SITE_XMAT: "site_xmat"}


def gather_plan(sim: WristSim, light: bool, tool_wrench: bool) -> tuple[np.ndarray, dict]:
    """What a batch reads of each world after a period: the plan (int32 rows of ``advance_lib`` field, start,
    count) and each read's columns in a gathered row. ``light``: the worlds sync kinematics only (the weld
    violation at the end of the period is then computed from the loop-closure bodies' poses);
    ``tool_wrench``: the tool's force/torque sensors are read."""
    rows: list = []
    cols: dict[str, slice] = {}

    def add(name: str, field: int, start: int, count: int) -> None:
        c = sum(r[2] for r in rows)
        rows.append((field, start, count))
        cols[name] = slice(c, c + count)

    add("qpos", A.F_QPOS, 0, sim.model.nq)
    add("coupler_angles", A.F_ANGLES, 9 * sim.coupler_id, 2)
    add("coupler_cvel", A.F_CVEL, 6 * sim.coupler_id, 6)
    add("ps_rate", A.F_QVEL, sim._vadr_ps, 1)
    add("peak", A.F_PEAK, 0, 1)
    if light:  # the weld violation at the end of the period (``read_closure``)
        for b in [sim.coupler_id] + list(sim._end_ids):
            add(f"xpos{b}", A.F_XPOS, 3 * b, 3)
            add(f"xquat{b}", A.F_XQUAT, 4 * b, 4)
    if tool_wrench:
        add("tool_R", A.F_SITE_XMAT, 9 * sim._tool_site, 9)
        add("tool_f", A.F_SENSOR, sim._force_adr, 3)
        add("tool_t", A.F_SENSOR, sim._torque_adr, 3)
    return np.array(rows, dtype=np.int32).reshape(-1, 3), cols


def watch_rows(c, direction, armed, passed, released, due, peak_time, peak_speed, peak_vel, active, body: int,
               mass_gone: float, inertia_gone: float, reach: float) -> np.ndarray:
    """Rows (L, ``WATCH_SIZE``) of L worlds' release watches (the layout in ``advance_lib``): the plane's point
    and normal (L, 3), the flags and the peak so far (L,) and (L, 3), active (L,) bool, and what every world
    shares (the ball's body id, its mass and inertia once gone, the reach)."""
    W = np.empty((len(active), A.WATCH_SIZE))
    W[:, A.W_C:A.W_C + 3] = c
    W[:, A.W_DIR:A.W_DIR + 3] = direction
    W[:, A.W_ARMED], W[:, A.W_PASSED], W[:, A.W_RELEASED], W[:, A.W_DUE] = armed, passed, released, due
    W[:, A.W_PEAK_TIME], W[:, A.W_PEAK_SPEED] = peak_time, peak_speed
    W[:, A.W_PEAK_VEL:A.W_PEAK_VEL + 3] = peak_vel
    W[:, A.W_ACTIVE] = active
    W[:, A.W_BODY], W[:, A.W_MASS_GONE], W[:, A.W_INERTIA_GONE], W[:, A.W_REACH] = body, mass_gone, inertia_gone, reach
    return W


def read_watch(W: np.ndarray) -> dict[str, np.ndarray]:
    """What the compiled advance leaves in release watches' rows ``W`` (L, ``WATCH_SIZE``): the flags (L,) bool and
    the peak so far."""
    flags = W[:, [A.W_ARMED, A.W_PASSED, A.W_RELEASED, A.W_DUE]] != 0.0
    return {"armed": flags[:, 0], "passed": flags[:, 1], "released": flags[:, 2], "due": flags[:, 3],
            "peak_time": W[:, A.W_PEAK_TIME], "peak_speed": W[:, A.W_PEAK_SPEED],
            "peak_vel": W[:, A.W_PEAK_VEL:A.W_PEAK_VEL + 3]}


class BatchSim:
    """``n`` worlds' simulators, stepped one control period (``ctrl_dt``) at a time. ``first``: world 0's
    simulator (every world has the same layout; randomisation may rebuild a world's model, not change it).
    ``compiled``: use the compiled advance where it can be built (``lib`` is None otherwise, and the caller
    steps each world through its ``WristSim``). ``light``: after a period, sync kinematics only (else
    ``mj_forward`` with the sensors). ``meter``: the worlds carry a contact meter (``sim.add_contact_meter``)
    whose window each period restarts. ``watch``: each world has a release watch (``watch``, (n, ``WATCH_SIZE``),
    rows written by ``watch_rows`` before a period and read by ``read_watch`` after it)."""

    def __init__(self, n: int, first: WristSim, ctrl_dt: float, light: bool, tool_wrench: bool, meter: bool,
                 compiled: bool = True, watch: bool = False):
        self.n = n
        self.compiled = bool(compiled)
        self.lib = A.load() if self.compiled else None
        self.light = bool(light)
        self.sync = A.SYNC_KINEMATICS if light else A.SYNC_FORWARD
        self.nstep = int(round(ctrl_dt / first.timestep))
        self.ctrl_idx = np.asarray(first._act_ids, dtype=np.int32)
        self.meter = bool(meter)
        self.handles = np.zeros((n, A.HANDLE_COLUMNS), dtype=np.uint64)
        self.watch = np.zeros((n, A.WATCH_SIZE)) if watch else None
        self.sims: list = [None] * n  # the simulator each handle row was written for
        self.blocked = np.zeros(n, dtype=bool)  # worlds the compiled advance cannot step
        self.plan, self.cols = gather_plan(first, light, tool_wrench)
        self.width = int(self.plan[:, 2].sum())  # columns of a gathered row
        self._qadr = (first._qadr_ps, first._qadr_q1, first._qadr_m3, first._qadr_motor)
        self._coupler, self._ends = first.coupler_id, list(first._end_ids)
        self._pool: A.Pool | None = None

    # ------------------------------------------------------------------ the compiled advance
    def attach(self, i: int, sim: WristSim, ctrl_dt: float, meter: np.ndarray | None = None) -> None:
        """World i's handle-table row for ``sim`` (after a reset: randomisation may rebuild a simulator); a
        world the compiled call cannot step as ``WristSim.step`` would is marked blocked. ``meter``: the
        world's contact meter state (``sim.contact_meter_state``)."""
        row = self.handles[i]
        row[A.H_MODEL], row[A.H_DATA] = sim.model._address, sim.data._address
        row[A.H_PEAK] = sim._closure_peak.ctypes.data
        row[A.H_METER] = 0 if meter is None else meter.ctypes.data
        row[A.H_METER_SIZE] = 0 if meter is None else meter.size
        row[A.H_WATCH] = 0 if self.watch is None else self.watch[i].ctypes.data
        self.sims[i] = sim
        self.blocked[i] = ((self.meter and meter is None) or int(round(ctrl_dt / sim.timestep)) != self.nstep
                           or not np.array_equal(sim._act_ids, self.ctrl_idx))

    def attached(self, i: int, sim: WristSim) -> bool:
        return self.sims[i] is sim

    def set_latency(self, idx: list, substeps: list) -> None:
        """The worlds' actuation latency this period, in substeps (0: none): that many substeps run on the
        previous motor references before the new ones take over (``VSWristEnv._advance``)."""
        self.handles[idx, A.H_LATENCY] = substeps

    def steps(self, idx: list) -> bool:
        """Whether the compiled advance steps the (attached) worlds ``idx``."""
        return self.lib is not None and not self.blocked[idx].any()

    def advance(self, worlds: np.ndarray, theta: np.ndarray, status: np.ndarray,
                seconds: np.ndarray | None = None, out: np.ndarray | None = None) -> int:
        """One period of ``worlds`` (int32) on the calling thread: motor references ``theta`` (len(worlds), 4),
        ``status`` written per world, ``seconds`` accumulating the CPU time inside ``mj_step`` (or None),
        ``out`` (len(worlds), width) the gathered reads (or None). Returns how many worlds are not OK."""
        return A.advance(self.lib, self.handles, worlds, theta, self.ctrl_idx, self.nstep, self.sync, status,
                         seconds, None if out is None else self.plan, out)

    def pool(self, threads: int) -> A.Pool:
        """The compiled advance's pool of ``threads`` threads (made here at first use, and again in a forked
        child: threads do not survive a fork). ``submit`` it with ``submit``."""
        pool = self._pool
        if pool is None or pool.pid != os.getpid() or pool.threads != threads:
            if pool is not None and pool.pid == os.getpid():
                pool.close()
            pool = self._pool = A.Pool(self.lib, threads)
        return pool

    def submit(self, pool: A.Pool, worlds, theta, status, seconds, bounds, released: int, out) -> None:
        """``pool.submit`` of a period of ``worlds`` in chunks ``bounds`` (see ``advance_lib.Pool``)."""
        pool.submit(self.handles, worlds, theta, self.ctrl_idx, self.nstep, self.sync, status, seconds, bounds,
                    released=released, plan=self.plan, out=out)

    def settle(self, sims: list, status: np.ndarray) -> list:
        """What ``WristSim.step`` and its sync leave on each simulator, from the compiled call's status: synced
        (OK) or stale (DIVERGED). Returns the statuses as a list."""
        light = self.light
        st = status.tolist()
        for sim, s in zip(sims, st):
            if s == OK:
                sim._stale, sim._light = False, light
            elif s == DIVERGED:
                sim._stale = True
        return st

    def close(self) -> None:
        if self._pool is not None:
            self._pool.close()
        self._pool = None

    def __getstate__(self):
        # the compiled library, the pool and the worlds' addresses belong to this process: rebuilt on loading
        state = dict(self.__dict__)
        state["lib"], state["_pool"], state["sims"] = None, None, [None] * self.n
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.lib = A.load() if self.compiled else None

    # ------------------------------------------------------------------ the reads over arrays
    def gather(self, sims: list) -> np.ndarray:
        """The gathered reads of ``sims`` in Python (worlds the compiled advance did not step or read), from
        their synced MjData."""
        G = np.empty((len(sims), self.width))
        for k, s in enumerate(sims):
            parts = [s._closure_peak if f == A.F_PEAK
                     else coupler_angles(*s.data.xmat.reshape(-1)[a:a + 9:3].tolist()) if f == A.F_ANGLES
                     else getattr(s.data, GATHER_FIELDS[f]).reshape(-1)[a:a + n] for f, a, n in self.plan.tolist()]
            G[k] = np.concatenate(parts)
        return G

    def qpos(self, G: np.ndarray) -> np.ndarray:
        """The joint positions (N, nq) of gathered rows."""
        return G[:, self.cols["qpos"]]

    def read_posture(self, G: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Measured postures (N, 3) and spring deflections (N, 3) (``WristSim.posture``, ``deflections``), and
        the joint positions they come from (N, nq)."""
        ps, q1, m3, _ = self._qadr
        Q = G[:, self.cols["qpos"]]
        P = np.empty((len(G), 3))
        P[:, :2] = G[:, self.cols["coupler_angles"]]  # computed in the gather
        P[:, 2] = Q[:, ps]
        return P, Q[:, q1] - Q[:, m3], Q

    def read_motor_angles(self, Q: np.ndarray) -> np.ndarray:
        """``WristSim.motor_angles`` of every world (N, 4) from its joint positions."""
        return Q[:, self._qadr[3]]

    def read_tool_wrench(self, G: np.ndarray) -> np.ndarray:
        """``WristSim.tool_wrench`` of every world (N, 6): the tool's force/torque sensors rotated to the base."""
        c = self.cols
        return tool_wrench_of(G[:, c["tool_R"]].reshape(len(G), 3, 3), G[:, c["tool_f"]], G[:, c["tool_t"]])

    def read_posture_rate(self, G: np.ndarray, P: np.ndarray) -> np.ndarray:
        """d/dt of the postures (N, 3) (``WristSim.posture_rate``; P: the postures just read)."""
        C = G[:, self.cols["coupler_cvel"]]
        return np.stack(posture_rate_terms(C[:, 0], C[:, 1], C[:, 2], P[:, 0], P[:, 1],
                                           G[:, self.cols["ps_rate"]][:, 0], np.sin, np.cos), axis=1)

    def read_closure(self, G: np.ndarray, sims: list) -> list:
        """``WristSim.loop_closure_peak`` of every world (after the period's sync). After a light sync the
        monitor has not seen the final state: its weld violation (``native.weld_opening``) over arrays."""
        c = self.cols
        light = self.light
        peak = G[:, c["peak"]][:, 0]
        stale = [k for k, s in enumerate(sims) if s._stale or s._light != light]
        if not light:
            out = peak.tolist()
        else:
            cid = self._coupler
            pc, qc = G[:, c[f"xpos{cid}"]].T, G[:, c[f"xquat{cid}"]].T  # columns of worlds
            worst = np.zeros(len(G))
            for e in self._ends:
                opening = weld_opening(pc, qc, G[:, c[f"xpos{e}"]].T, G[:, c[f"xquat{e}"]].T, np.sqrt, np.arccos,
                                       np.minimum)
                worst = np.maximum(worst, np.maximum(*opening))
            out = np.where(worst > peak, worst, peak).tolist()
        for k in stale:  # not synced as the advance syncs (a failed step): the world's own accessor
            out[k] = sims[k].loop_closure_peak()
        return out
