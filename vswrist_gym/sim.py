"""The VS-Wrist simulator: the MuJoCo model of ``vswrist_gym.model`` with springs and motor dynamics.

Quick reference (angles rad, torques N m, forces N, base frame = MuJoCo world frame, X along the forearm)::

    sim = WristSim(params=None, scene_fn=None)   # sim.model / sim.data are the MuJoCo objects
    sim.reset(u=(0.0, 0.0), ps=0.0, lam=0.0)     # closed chain at posture u, springs preloaded by lam, at rest
    sim.set_motor_references(theta)              # (4,): PM motors A, B, C + PS motor
    sim.step(duration_s)                         # a whole number of physics substeps (sim.timestep)
    sim.posture() -> (3,)                        # measured RUD, FE of the coupler, PS
    sim.posture_rate() -> (3,)
    sim.apply_wrench(force, torque)              # on the hand, held until changed (or reset)
    sim.spring_torques(), sim.deflections()      # (3,) each
    sim.motor_angles(), sim.motor_velocities(), sim.motor_torques()   # (4,) each
    sim.tool_wrench() -> (6,)                    # force, torque the hand exerts on the tool, base frame
    sim.loop_closure_error() -> float            # largest weld violation (m or rad)
    sim.loop_closure_peak() -> float             # the same, worst over the last step's substeps
    s = sim.get_state(); sim.set_state(s)        # exact restart

The springs and the motors' setpoint dynamics act inside every physics substep (``model.native``: MuJoCo
plugins named in the model, or the reference callbacks under ``VSWRIST_NATIVE=0``), so ``step`` is one
``mj_step(m, d, n)`` call. Quantities derived from positions (body poses, sensors, actuator
forces) are recomputed lazily with one ``mj_forward`` the first time an accessor needs them after ``step``;
sensors are evaluated only then (they are disabled inside the substeps to save time). ``sync_kinematics()``
updates only poses and velocities (for callers that read no sensors); ``posture()`` then reads those.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .kinematics import LEG_NAMES, RangeOfMotionError, WristKinematics
from .model import native
from .model.builder import SceneFn, build_model
from .model.native import CLOSURE_TAG, weld_violation
from .model.plugin_lib import CONTACT_PLUGIN, CONTACT_STATE_SIZE, DRIVE_PLUGIN
from .params import WristParams, load_params
from .stiffness import PostureTerms, lambda_range, motor_references

__all__ = ["WristSim", "SimulationError", "RangeOfMotionError"]

_SENSOR_FLAG = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
_BODY = mujoco.mjtObj.mjOBJ_BODY
_JOINT = mujoco.mjtObj.mjOBJ_JOINT


class SimulationError(RuntimeError):
    """The physics diverged (MuJoCo reported bad accelerations and reset the state) or produced NaN."""


# what ``WristSim.step`` (and a batch's compiled advance, ``model.advance_lib``) reports for a diverged step
DIVERGED_MESSAGE = ("MuJoCo reported NaN or huge positions/velocities/accelerations and reset the state; the "
                    "timestep or constraint settings are too coarse for this motion")


def coupler_angles(r0: float, r3: float, r6: float) -> tuple[float, float]:
    """The measured RUD and FE (rad): ZYX Euler angles alpha_y, alpha_z of the coupler, from its rotation matrix's
    entries R[0, 0], R[1, 0], R[2, 0] (``r0``, ``r3``, ``r6`` of ``xmat``). One world's numbers: a batch's
    compiled advance computes them in C as its gather (``advance_lib.F_ANGLES``, with the C library's asin and
    atan2, which ``math`` calls), since NumPy's arcsin and arctan2 may differ from math's in the last bit."""
    return math.asin(max(-1.0, min(1.0, -r6))), math.atan2(r3, r0)


def posture_rate_terms(wx, wy, wz, ay, az, ps_rate, sin, cos) -> tuple:
    """d/dt of (RUD, FE, PS) (rad/s) from the coupler's angular velocity (wx, wy, wz) (rad/s, world frame) at the
    measured RUD ``ay`` and FE ``az`` and the PS joint's rate: one world's floats with math's ``sin``/``cos``, or
    arrays of worlds with NumPy's (which round as math's)."""
    sz, cz = sin(az), cos(az)
    ax_rate = (cz * wx + sz * wy) / cos(ay)
    return -sz * wx + cz * wy, wz + sin(ay) * ax_rate, ps_rate


def tool_wrench_of(R: np.ndarray, force: np.ndarray, torque: np.ndarray) -> np.ndarray:
    """(force N, torque N m) (..., 6) in the base frame from the tool site's rotation ``R`` (..., 3, 3) and its
    force/torque sensors' readings (..., 3) in the site frame: one world's or a batch's (``batch_sim``)."""
    FT = np.concatenate([force, torque], axis=-1).reshape(force.shape[:-1] + (2, 3, 1))
    return (R[..., None, :, :] @ FT).reshape(R.shape[:-2] + (6,))


def add_contact_meter(spec: mujoco.MjSpec, name: str, body, geom1: str, geom2: str | None = None) -> bool:
    """Adds a ``vswrist.contact`` plugin instance ``name`` to a spec that runs the compiled physics (it names the
    VS-Wrist drive plugin), referenced by ``body`` (an MjsBody): after every substep's constraint solve it adds
    the normal forces of the contacts of geom ``geom1`` (with ``geom2``, or with anything), counts the substep
    and keeps the first contact's time, position and the body's velocity (``contact_meter_state``). Returns
    False, adding nothing, where the spec runs the reference callbacks (no plugins)."""
    if not any(p.plugin_name == DRIVE_PLUGIN for p in spec.plugins):
        return False
    spec.activate_plugin(CONTACT_PLUGIN)
    inst = spec.add_plugin(name=name, plugin_name=CONTACT_PLUGIN, active=True)
    inst.config = {"geom1": geom1} if geom2 is None else {"geom1": geom1, "geom2": geom2}
    body.plugin.name = name
    body.plugin.active = True
    return True


def contact_meter_state(model: mujoco.MjModel, data: mujoco.MjData, name: str) -> np.ndarray | None:
    """A view of the plugin state of contact meter ``name`` (``model.plugin_lib.CONTACT_STATE``: force sum,
    substeps, touched, touch time, position (3), velocity (3)), or None where the model has no such meter."""
    i = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_PLUGIN, name)
    if i < 0:
        return None
    adr = int(model.plugin_stateadr[i])
    return data.plugin_state[adr:adr + CONTACT_STATE_SIZE]


class WristSim:
    """MuJoCo simulation of one VS-Wrist built from one parameter set.

    ``scene_fn(spec)`` may add task bodies and geoms (world or the ``tool`` body) before compilation.
    ``backend``: "c" (the compiled plugin; ``native.NativeBuildError`` without a C compiler), "python" (the
    reference callbacks, for tests and comparisons) or None (the plugin, or the reference under
    ``VSWRIST_NATIVE=0``).
    """

    def __init__(self, params: WristParams | str | None = None, scene_fn: SceneFn | None = None,
                 backend: str | None = None):
        self.params = load_params(params)
        self.kin = WristKinematics(self.params)
        self.backend = native.install(backend or "auto")
        self._callbacks = self.backend == "python"
        with native.compiling():
            self.model = build_model(self.params, scene_fn, native.physics(self.backend))
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.timestep = float(m.opt.timestep)
        jid = lambda name: mujoco.mj_name2id(m, _JOINT, name)  # noqa: E731
        leg_joints = [jid(f"leg{n}_q{i}") for n in LEG_NAMES for i in range(1, 5)]
        motor_joints = [jid(f"motor_{n}") for n in LEG_NAMES] + [jid("ps")]
        self._qadr_legs = m.jnt_qposadr[leg_joints].copy()
        self._qadr_q1 = self._qadr_legs[0::4].copy()
        self._qadr_motor = m.jnt_qposadr[motor_joints].copy()
        self._vadr_motor = m.jnt_dofadr[motor_joints].copy()
        self._qadr_ps = int(m.jnt_qposadr[jid("ps")])
        self._vadr_ps = int(m.jnt_dofadr[jid("ps")])
        self._act_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, f"motor_{n}")
                                  for n in ("A", "B", "C", "ps")])
        self._act_adr = m.actuator_actadr[self._act_ids].copy()
        self.coupler_id = mujoco.mj_name2id(m, _BODY, "coupler")
        self.hand_id = mujoco.mj_name2id(m, _BODY, "hand")
        self.tool_id = mujoco.mj_name2id(m, _BODY, "tool")
        self._end_ids = [mujoco.mj_name2id(m, _BODY, f"leg{n}_end") for n in LEG_NAMES[1:]]
        self._tool_site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "tool_site")
        sens = lambda name: int(m.sensor_adr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)])  # noqa: E731
        self._force_adr, self._torque_adr = sens("tool_force"), sens("tool_torque")
        self._K, self._delta0 = self.params.spring.K, self.params.spring.delta0
        rom = self.params.range_of_motion
        self._ps_range = (rom.ps_min, rom.ps_max)
        self._bad = [int(w) for w in (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS,
                                      mujoco.mjtWarning.mjWARN_BADQVEL)]
        m.opt.disableflags |= _SENSOR_FLAG
        # views into MjData's fixed buffers (MuJoCo never reallocates them), so that the per-step accessors
        # skip the attribute look-ups and fancy indexing of the generic path
        d = self.data
        self._qpos, self._qvel = d.qpos, d.qvel
        self._xpos, self._xquat, self._ctrl = d.xpos, d.xquat, d.ctrl
        self._coupler_xmat, self._coupler_cvel = d.xmat[self.coupler_id], d.cvel[self.coupler_id]
        self._qadr_m3 = self._qadr_motor[:3].copy()
        a0 = int(self._act_ids[0])
        contiguous = np.array_equal(self._act_ids, np.arange(a0, a0 + 4)) and \
            np.array_equal(self._act_adr, np.arange(int(self._act_adr[0]), int(self._act_adr[0]) + 4))
        self._ctrl_idx = slice(a0, a0 + 4) if contiguous else self._act_ids
        self._act_idx = slice(int(self._act_adr[0]), int(self._act_adr[0]) + 4) if contiguous else self._act_adr
        self._warn_number = d.warning.number  # live view of the warning counters
        self._xfrc_hand = d.xfrc_applied[self.hand_id]
        self._tool_R = d.site_xmat[self._tool_site].reshape(3, 3)
        self._tool_f = d.sensordata[self._force_adr:self._force_adr + 3]
        self._tool_t = d.sensordata[self._torque_adr:self._torque_adr + 3]
        # the closure monitor keeps the worst weld violation it sees in the ``closure`` plugin instance's state
        # (the reference: userdata[slot] of builder's ``vswrist_closure`` field): one check per substep inside
        # mj_step, with no Python in the loop
        if self._callbacks:
            slot = int(m.numeric(CLOSURE_TAG).data[0])
            self._closure_peak = d.userdata[slot:slot + 1]
        else:
            adr = int(m.plugin_stateadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_PLUGIN, "closure")])
            self._closure_peak = d.plugin_state[adr:adr + 1]
        self._stale = True   # nothing derived from the positions is current (after step)
        self._light = False  # only poses and velocities are current (after sync_kinematics)
        self.reset()

    # ------------------------------------------------------------------ state
    @property
    def time(self) -> float:
        return float(self.data.time)

    def reset(self, u=(0.0, 0.0), ps: float = 0.0, lam: float = 0.0) -> None:
        """Closed chain at posture u = (RUD, FE), PS angle ps, internal torque lam (N m), at rest.

        The motors stand at ``stiffness.motor_references(u, lam)`` (references and filter states too), so the
        springs carry exactly lam N; the applied wrench is cleared. Gravity, if on, acts from here on.
        """
        WristSim.reset_many([self], [u], [ps], [lam])

    @staticmethod
    def reset_many(sims: list, u, ps, lam) -> None:
        """``reset`` of many simulators of one geometry (a batch's worlds that reset together): sims[k] at
        posture u[k], PS angle ps[k], internal torque lam[k]. The kinematics (joint angles, internal-torque
        basis) of all postures is one pass of NumPy calls over the stack, the same numbers as one by one."""
        kin = sims[0].kin
        if any(s.kin.params.geometry != kin.params.geometry for s in sims):
            for s, uk, pk, lk in zip(sims, u, ps, lam):
                WristSim.reset_many([s], [uk], [pk], [lk])
            return
        U = np.array([s.kin.check_posture(np.asarray(uk, dtype=float)) for s, uk in zip(sims, u)])
        PS = [float(p) for p in ps]
        for s, p in zip(sims, PS):
            if not (s._ps_range[0] <= p <= s._ps_range[1]):
                raise RangeOfMotionError(f"ps = {p:.4f} rad is outside the range of motion "
                                         f"[{s._ps_range[0]:.4f}, {s._ps_range[1]:.4f}] rad")
        # q1 and N once, for both the range check and the motor references (each would compute N again)
        Q = kin.joint_angles(U)
        N = kin.internal_torque_basis(U)
        LAM, TERMS = [float(lk) for lk in lam], []
        for s, uk, q, nk, lk in zip(sims, U, Q, N, LAM):  # every check before any simulator changes
            terms = PostureTerms(u=uk, q1=q[0::4], Ja=None, N=nk, Ha=None)
            lo, hi = lambda_range(uk, s.params, terms=terms)
            if not (lo - 1e-9 <= lk <= hi + 1e-9):
                raise ValueError(f"lam = {lk:.6g} N m is outside the range the motor torque and deflection limits "
                                 f"allow at u = {uk}: [{lo:.6g}, {hi:.6g}] N m")
            TERMS.append(terms)
        for s, uk, q, terms, p, lk in zip(sims, U, Q, TERMS, PS, LAM):
            m, d = s.model, s.data
            mujoco.mj_resetDataKeyframe(m, d, 0)
            theta = np.append(motor_references(uk, lk, s.params, terms=terms), p)
            d.qpos[s._qadr_legs] = q
            d.qpos[s._qadr_motor] = theta
            d.ctrl[s._act_ids] = theta
            d.act[s._act_adr] = theta
            s._forward()

    def get_state(self) -> np.ndarray:
        """Everything needed for an exact restart (MuJoCo's integration state: time, qpos, qvel, act,
        warm start, ctrl, applied forces...)."""
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(self.model, spec))
        mujoco.mj_getState(self.model, self.data, state, spec)
        return state

    def set_state(self, state: np.ndarray) -> None:
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.asarray(state, dtype=float)
        size = mujoco.mj_stateSize(self.model, spec)
        if state.shape != (size,):
            raise ValueError(f"state must have shape ({size},) as returned by get_state(), got {state.shape}")
        mujoco.mj_setState(self.model, self.data, state, spec)
        self._forward()

    # ---------------------------------------------------------------- actions
    def set_motor_references(self, theta) -> None:
        """Motor references (4,), rad: PM motors A, B, C (the paper's theta) and the PS motor."""
        if type(theta) is np.ndarray and theta.shape == (4,) and theta.dtype == np.float64:
            a, b, c, e = theta.tolist()  # the hot path: x - x is 0 only for finite x
            if a - a == 0.0 and b - b == 0.0 and c - c == 0.0 and e - e == 0.0:
                self._ctrl[self._ctrl_idx] = theta
                return
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (4,) or not np.isfinite(theta).all():
            raise ValueError(f"motor references must be 4 finite angles in rad (A, B, C, PS), got {theta!r}")
        self._ctrl[self._ctrl_idx] = theta

    def apply_wrench(self, force=(0.0, 0.0, 0.0), torque=(0.0, 0.0, 0.0)) -> None:
        """External force (N) and torque (N m) on the hand at its centre, base frame, held until changed."""
        f, t = np.asarray(force, dtype=float), np.asarray(torque, dtype=float)
        if f.shape == (3,) and t.shape == (3,) and np.isfinite(f).all() and np.isfinite(t).all():
            x = self._xfrc_hand  # fast path: two plain 3-vectors
            x[:3] = f
            x[3:] = t
            return
        w = np.concatenate([f.ravel(), t.ravel()])
        if w.shape != (6,) or not np.all(np.isfinite(w)):
            raise ValueError(f"force and torque must be finite 3-vectors (N, N m), got {force!r}, {torque!r}")
        self.data.xfrc_applied[self.hand_id] = w

    @staticmethod
    def apply_wrenches(sims: list, wrenches: np.ndarray) -> None:
        """``apply_wrench`` of many simulators (a batch's worlds): row k of ``wrenches`` (N, 6), (force N, torque
        N m), to ``sims[k]``; checked once over the array."""
        w = np.asarray(wrenches, dtype=float)
        if w.shape != (len(sims), 6) or not np.isfinite(w).all():
            raise ValueError(f"wrenches must be finite, one (force, torque) row of 6 per simulator "
                             f"({len(sims)}), got shape {w.shape}")
        for s, row in zip(sims, w):
            s._xfrc_hand[:] = row

    def step(self, duration_s: float, restart_peak: bool = True) -> None:
        """Advance the physics by ``duration_s`` (a whole number of substeps of ``self.timestep``).
        ``restart_peak=False`` extends the previous step's ``loop_closure_peak`` (one period in two calls)."""
        n = int(round(duration_s / self.timestep))
        if n < 1 or abs(n * self.timestep - duration_s) > 1e-9 * max(1.0, duration_s):
            raise ValueError(f"duration_s = {duration_s!r} s must be a positive multiple of the timestep "
                             f"{self.timestep} s")
        if restart_peak:
            self._closure_peak[0] = 0.0
        if self._callbacks:  # another WristSim may have switched the process to the plugin since
            native.ensure_callbacks()
        mujoco.mj_step(self.model, self.data, n)
        self._stale = True
        w = self._warn_number
        if w[self._bad[0]] or w[self._bad[1]] or w[self._bad[2]]:
            raise SimulationError(DIVERGED_MESSAGE)

    # -------------------------------------------------------------- measures
    def _forward(self) -> None:
        m = self.model
        if self._callbacks:
            native.ensure_callbacks()
        m.opt.disableflags &= ~_SENSOR_FLAG
        mujoco.mj_forward(m, self.data)
        m.opt.disableflags |= _SENSOR_FLAG
        self._stale = False
        self._light = False

    def _sync(self) -> None:
        if self._stale or self._light:
            self._forward()

    def sync(self) -> None:
        """Bring everything derived from the state up to date (body poses, sensors, actuator and constraint
        forces) with one ``mj_forward``, if a step made them stale. Accessors do this themselves."""
        if self._stale or self._light:
            self._forward()

    def sync_kinematics(self) -> None:
        """After a step, bring only body/site poses and body velocities (``xpos``, ``xmat``, ``xquat``,
        ``site_xpos``, ``cvel``...) up to date: ``mj_kinematics`` + ``mj_comPos`` + ``mj_comVel``, about a fifth
        of the cost of ``mj_forward``, for callers that read no sensors. The same values as the full forward;
        sensors, actuator forces and contacts are recomputed by the next accessor that needs them."""
        if self._stale:
            m, d = self.model, self.data
            mujoco.mj_kinematics(m, d)
            mujoco.mj_comPos(m, d)
            mujoco.mj_comVel(m, d)
            self._stale = False
            self._light = True

    def posture(self) -> np.ndarray:
        """Measured (RUD, FE, PS), rad: ZYX Euler angles alpha_y, alpha_z of the coupler, and the PS joint."""
        if self._stale:
            self._forward()
        R = self._coupler_xmat.tolist()
        ay, az = coupler_angles(R[0], R[3], R[6])
        return np.array([ay, az, self._qpos[self._qadr_ps]])

    def posture_rate(self) -> np.ndarray:
        """Time derivative of ``posture()`` (rad/s), from the coupler's angular velocity."""
        if self._stale:
            self._forward()
        wx, wy, wz = self._coupler_cvel.tolist()[:3]
        R = self._coupler_xmat.tolist()
        ay, az = coupler_angles(R[0], R[3], R[6])
        return np.array(posture_rate_terms(wx, wy, wz, ay, az, self._qvel[self._vadr_ps], math.sin, math.cos))

    def deflections(self) -> np.ndarray:
        """Spring deflections delta = q1 - theta (3,), rad."""
        q = self._qpos
        return q[self._qadr_q1] - q[self._qadr_m3]

    def spring_torques(self) -> np.ndarray:
        """Spring torques on the legs' first joints tau_s = -2K sinh(delta/delta0) (3,), N m."""
        return -2.0 * self._K * np.sinh(self.deflections() / self._delta0)

    def motor_angles(self) -> np.ndarray:
        """Motor angles (4,), rad: rotors A, B, C (theta) and the PS joint."""
        return self._qpos[self._qadr_motor]  # fancy indexing: already a copy

    def motor_velocities(self) -> np.ndarray:
        return self._qvel[self._vadr_motor]  # fancy indexing: already a copy

    def motor_references(self) -> np.ndarray:
        """The references last set (4,), rad."""
        return self.data.ctrl[self._ctrl_idx].copy()

    def motor_filter_states(self) -> np.ndarray:
        """The servo setpoints the position loops track (4,), rad: the rate-limited low-pass of the references,
        held within kd * speed_limit / kp of the motor angles."""
        return self.data.act[self._act_idx].copy()

    def motor_torques(self) -> np.ndarray:
        """Motor torques (4,), N m (after the torque limit)."""
        self._sync()
        return self.data.actuator_force[self._act_ids].copy()

    def joint_angles(self) -> np.ndarray:
        """The 12 leg joint angles [q_A, q_B, q_C] (DH convention, as ``WristKinematics.joint_angles``)."""
        return self.data.qpos[self._qadr_legs].copy()

    def coupler_pose(self) -> np.ndarray:
        """Coupler frame T_b^c (4x4)."""
        if self._stale:  # poses: sync_kinematics is enough
            self._forward()
        T = np.eye(4)
        T[:3, :3] = self.data.xmat[self.coupler_id].reshape(3, 3)
        T[:3, 3] = self.data.xpos[self.coupler_id]
        return T

    def hand_position(self) -> np.ndarray:
        if self._stale:
            self._forward()
        return self.data.xpos[self.hand_id].copy()

    def tool_wrench(self) -> np.ndarray:
        """(force N, torque N m) (6,) that the hand exerts on the tool (and whatever is attached to it),
        base frame, torque about the tool mount. Zero with nothing attached."""
        if self._stale or self._light:
            self._forward()
        return tool_wrench_of(self._tool_R, self._tool_f, self._tool_t)

    def loop_closure_error(self) -> float:
        """Largest violation of the loop-closure welds: position (m) or rotation angle (rad), whichever is larger."""
        if self._stale:  # poses: sync_kinematics is enough
            self._forward()
        return weld_violation(self.data.xpos, self.data.xquat, self.coupler_id, self._end_ids)

    def loop_closure_peak(self) -> float:
        """``loop_closure_error`` at its worst over the last ``step``: at the state it started from and after
        each of its substeps (the last one included), m or rad. The peaks of reference jumps last a few
        substeps, so the state at the end of a control period alone misses them. The closure plugin (or the
        reference callback) evaluates it once per substep."""
        if self._stale:
            self._forward()  # the monitor runs in mj_forward too, so the final state is now counted
            return float(self._closure_peak[0])
        peak = float(self._closure_peak[0])
        if self._light:  # poses are current but the monitor did not see the final state
            end = weld_violation(self.data.xpos, self.data.xquat, self.coupler_id, self._end_ids)
            return end if end > peak else peak
        return peak

    def warnings(self) -> dict[str, int]:
        """MuJoCo warnings raised so far (name -> count); empty when all is well."""
        return {mujoco.mjtWarning(i).name: int(w.number) for i, w in enumerate(self.data.warning) if w.number}
