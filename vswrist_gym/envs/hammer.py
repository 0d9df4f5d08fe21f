"""``VSWrist/Hammer-v1`` (and ``-v0``): swing a hammer and strike an anvil as fast as the springs allow.

The tool is a hammer: a light handle and a head (a capsule whose axis points along the swing, so that its end
face strikes) of mass ``head_mass`` at ``handle_length`` from the hand along the tool X axis; both are drawn
per episode from their config ranges. The posture reference is fixed, at a fixed RUD (``rud_range``) and PS = 0:
in v1, from ``swing_start_s`` it winds back from ``fe_start`` to ``fe_back`` (the fastest leg's motor at
``windup_speed`` x its speed limit, ``motor.speed_limit`` of the device preset), holds there ``windup_hold_s``,
then ramps flexion towards ``fe_end`` as fast as the motors allow (the leg whose motor turns fastest per radian
of FE at ``swing_speed`` x the speed limit, throughout): Throw's counter-movement, which lets the springs store
energy while it turns round. v0 (``fe_back`` = ``fe_start``) has no wind-up: the ramp starts at
``swing_start_s``. Gravity (along -Z_b) is across the swing, which moves the head horizontally. An anvil (a plate
facing the swing) stands where the head is at FE = ``fe_strike``.

A rigid wrist would bring the head to the anvil at the *rigid bound*: the speed limit times the lever (the
head's speed per radian of FE over the leg's speed per radian of FE, at the strike posture;
``info["rigid_speed"]``; ``info`` also holds ``struck``, ``impact_speed`` (m/s), ``impact_time`` (s) and
``impact_offset`` (m, from the nail), zeros before a strike). The springs in series with the motors let the
link outrun them: the motors lead, the springs deflect and store energy, and give it back. The agent sets the
stiffness (the internal torque ``lam`` that the three PM motors hold in ker(J_a^T), VSA-hammer style: Garabini
et al. ICRA 2011), and the posture channel may be ignored (the ``residual`` mode with ``posture_scale: 0`` is
the stiffness track).

Reward: on the step of the first strike, the head's speed along the anvil normal just before contact
(``impact``, m/s / ``scales.speed``); ``miss`` -1 on the last step if no strike came by ``strike_deadline_s``
after the forward swing began (a late strike earns no ``impact`` either); preload energy at a small weight.
Success: a strike by the deadline at a normal speed of at least ``success_speed_ratio`` x the rigid bound, on
the nail (the first contact within ``success_radius`` of where the nominal swing meets the anvil), with RUD and PS
within ``success_plane_error`` of the swing's until the strike: a hammer blow, not a flailing hit (uniform random
posture references whip the head about and reach 1.6 x the rigid bound on some episodes). The default ratio, 1.75,
lies between what flailing reached (at most 1.64) and what the hand-written schedule reaches (at least 1.88);
fixed stiffnesses reach it on some episodes.

The strike's instant and the head's speed just before it are exact to the substep (1 ms), not to the control
period: the ``vswrist.contact`` plugin on the head records the first substep that finds it on the anvil inside
the period's one ``mj_step`` call (``shared.PeriodMeanForce``; the Python reference steps substep by substep).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .base import VSWristEnv
from .episode import at_step, episode_history, task_field
from .ramp import fe_rate, leg_rate, swing_ramps
from .shared import PeriodMeanForce, add_mocap_box_body, frame_from_z, off_plane, quat_from_matrix

ANVIL_HALF = (0.05, 0.045, 0.008)  # m: along the handle, across the swing plane, thickness (along the normal)
HEAD_HALF_LENGTH = 0.02            # m, half the head's length along the swing (its axis)
NOMINAL_HEAD_MASS = 0.2            # kg, compiled in the model; each episode sets its own mass in place
IMPACT, MISS = 0, 1  # the columns of the task's reward terms (``HammerEnv.task_reward_terms``)


def head_inertia(mass: float, radius: float, half_length: float) -> np.ndarray:
    """Principal inertia (kg m^2) of a solid cylinder of ``mass`` about its centre, axis along local Z."""
    ix = mass * (3.0 * radius ** 2 + (2.0 * half_length) ** 2) / 12.0
    return np.array([ix, ix, 0.5 * mass * radius ** 2])


class HammerEnv(PeriodMeanForce, VSWristEnv):
    task = "hammer"

    @property
    def windup(self) -> bool:
        """Whether the swing starts with a wind-up (``fe_back`` < ``fe_start``)."""
        return self.tp["fe_back"] < self.tp["fe_start"]

    @property
    def task_id(self) -> str:
        """v1 winds up before the swing (a counter-movement, ``fe_back``); v0 swings from rest."""
        return "VSWrist/Hammer-v1" if self.windup else "VSWrist/Hammer-v0"

    summary = ("swing a hammer (random head mass and handle length) through a fixed, motor-speed-limited FE "
               "motion (v1: after a wind-up) and strike an anvil as fast as possible")
    success_text = ("a strike within {strike_deadline_s:g} s of the forward swing's start, at a normal speed "
                    ">= {success_speed_ratio:g} x the rigid bound (motor speed limit x lever), on the nail (the "
                    "first contact within {success_radius:g} m of where the nominal swing meets the anvil), RUD and "
                    "PS within {success_plane_error:g} rad of the swing's until then")
    task_spec = {
        "head_mass": ("interval", 0.001, 5.0),
        "handle_length": ("interval", 0.03, 0.4),
        "handle_mass": ("number", 0.001, 1.0),
        "handle_radius": ("number", 0.001, 0.03),
        "head_radius": ("number", 0.003, 0.05),
        "rud_range": ("interval", -0.8, 0.8),
        "fe_start": ("number", -0.78, 0.95),
        "fe_back": ("number", -0.78, 0.95),
        "fe_strike": ("interval", -0.78, 0.95),
        "fe_end": ("number", -0.78, 0.95),
        "swing_start_s": ("number", 0.0, 600.0),
        "windup_speed": ("number", 0.01, 1.0),
        "windup_hold_s": ("number", 0.0, 10.0),
        "swing_speed": ("number", 0.01, 1.0),
        "strike_deadline_s": ("number", 0.0, 600.0),
        "success_speed_ratio": ("number", 0.0, 100.0),
        "success_radius": ("number", 0.0, 1.0),
        "success_plane_error": ("number", 0.0, 10.0),
        "friction": ("number", 0.0, 5.0),
    }
    task_reward_terms = ("impact", "miss")
    @property
    def task_state(self) -> dict:
        """The episode's draws (the head's ``head_mass``, kg, at ``handle`` m; the swing's ``rud`` and ``fe_strike``,
        rad); what its reset computes from them (``swing_t0``: when the forward swing starts, s; ``rigid``: the rigid
        bound, m/s; ``normal``: the anvil's normal, into it; ``face``: the nail, m, base frame; ``t0``: the
        episode's t = 0 in simulator time, s); the first strike (``struck``; its time ``strike_t``, s, normal speed
        ``strike_speed``, m/s, distance from the nail ``strike_offset``, m, whether it came by the deadline,
        ``timely``, and the step in whose period it came, ``strike_step``); and the task's reward terms at each of
        the episode's control steps (``reward_terms``: ``impact`` and ``miss``, written as soon as they are known,
        so that a step only reads its row: the reset writes the miss of the last step, a strike in time its impact
        and takes the miss back). The swing's FE ramp (``_swing_t``, ``_swing_fe``) stays on each world: its length
        varies with the episode, and only the reset's reference table reads it."""
        return {"head_mass": ((), float), "handle": ((), float), "rud": ((), float), "fe_strike": ((), float),
                "swing_t0": ((), float), "rigid": ((), float), "normal": ((3,), float), "face": ((3,), float),
                "t0": ((), float), "struck": ((), bool), "strike_t": ((), float), "strike_speed": ((), float),
                "strike_offset": ((), float), "timely": ((), bool), "strike_step": ((), np.int64),
                "reward_terms": ((self.episode_steps + 1, len(self.task_reward_terms)), float)}

    _head_mass, _handle, _rud, _fe_strike, _swing_t0, _rigid, _normal, _face, _t0 = map(
        task_field, ("head_mass", "handle", "rud", "fe_strike", "swing_t0", "rigid", "normal", "face", "t0"))
    _ps = 0.0  # rad: the swing's PS, in whose plane the RUD path of the head lies

    def _validate_task(self) -> None:
        from .config import EnvConfigError
        tp = self.tp
        if not (tp["fe_start"] < tp["fe_strike"][0] and tp["fe_strike"][1] < tp["fe_end"]):
            raise EnvConfigError(f"'task.fe_start' < 'task.fe_strike' < 'task.fe_end' is required (the swing "
                                 f"passes the anvil), got {tp['fe_start']:g}, {list(tp['fe_strike'])}, "
                                 f"{tp['fe_end']:g}")
        if tp["fe_back"] > tp["fe_start"]:
            raise EnvConfigError(f"'task.fe_back' <= 'task.fe_start' is required (the wind-up turns back in "
                                 f"extension; equal: no wind-up), got {tp['fe_back']:g} > {tp['fe_start']:g}")

    # ------------------------------------------------------------------ scene
    def _scene(self, spec) -> None:
        tp = self.tp
        L = 0.5 * (tp["handle_length"][0] + tp["handle_length"][1])
        # the handle collides with nothing; only the head strikes (contype 2 against the anvil's conaffinity 2)
        spec.body("tool").add_geom(name="hammer_handle", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                                   fromto=[0.02, 0, 0, L, 0, 0], size=[tp["handle_radius"], 0, 0],
                                   mass=tp["handle_mass"], contype=0, conaffinity=0, rgba=[0.55, 0.4, 0.25, 1],
                                   group=1)
        head = spec.body("tool").add_body(name="hammer_head", pos=[L, 0, 0])
        r = tp["head_radius"]
        head.add_geom(name="task_head", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                      fromto=[0, -HEAD_HALF_LENGTH, 0, 0, HEAD_HALF_LENGTH, 0], size=[r, 0, 0],
                      mass=NOMINAL_HEAD_MASS, contype=2, conaffinity=0, condim=3,
                      friction=[tp["friction"], 0.005, 0.0001], rgba=[0.35, 0.35, 0.4, 1], group=1)
        body = add_mocap_box_body(spec, "task_anvil", [(ANVIL_HALF, (0, 0, -ANVIL_HALF[2]), None)],
                                  rgba=(0.45, 0.45, 0.5, 1), friction=tp["friction"])
        self._add_touch_sensor(spec, body, "anvil_touch", (ANVIL_HALF[0], ANVIL_HALF[1], ANVIL_HALF[2] + 0.01),
                               pos=(0, 0, -ANVIL_HALF[2] + 0.01))
        self._add_contact_meter(spec, head, "task_head", "task_task_anvil_0")

    def _scene_ids(self) -> None:
        m = self.model
        self._head_body = int(m.body("hammer_head").id)
        self._head_geom = int(m.geom("task_head").id)
        self._anvil_geom = int(m.geom("task_task_anvil_0").id)
        self._mocap = int(m.body("task_anvil").mocapid[0])
        self._touch_adr = self._sensor_adr("anvil_touch")
        self._find_contact_meter()

    # ------------------------------------------------------------------ episode
    def _task_reset(self, rng):
        tp = self.tp
        head_mass = float(rng.uniform(*tp["head_mass"]))
        handle = float(rng.uniform(*tp["handle_length"]))
        rud = float(rng.uniform(*tp["rud_range"]))
        fe_strike = float(rng.uniform(*tp["fe_strike"]))
        ts = self._ep.task
        ts.put(0, head_mass=head_mass, handle=handle, rud=rud, fe_strike=fe_strike)
        ts.reward_terms[0, self.episode_steps, MISS] = -1.0  # unless a strike comes in time
        m = self.model
        # in place, like the base's tool-mass randomisation (no recompilation; MuJoCo's constraint scaling
        # keeps the compiled nominal head)
        m.body_pos[self._head_body] = (handle, 0.0, 0.0)
        m.body_mass[self._head_body] = head_mass
        # the capsule's axis is the body's Y axis: permute the cylinder's (x, x, z) inertia to (x, z, x)
        ix, _, iz = head_inertia(head_mass, tp["head_radius"], HEAD_HALF_LENGTH)
        m.body_inertia[self._head_body] = (ix, iz, ix)
        self._swing_t = self._swing_fe = None  # the swing's ramp: _reset_worlds, over the worlds resetting together
        return np.array([rud, tp["fe_start"]]), self._ps, -1.0

    @classmethod
    def _reset_worlds(cls, worlds: list) -> None:
        """The swing's FE ramp of each world (``ramp.swing_ramps``: over arrays for many worlds at once), and when
        its forward swing starts."""
        cls._strike_geometry(worlds)
        first = worlds[0]
        tp = first.tp
        limit = first.nominal_params.motor.speed_limit
        if first.windup:
            points, speeds = (tp["fe_start"], tp["fe_back"], tp["fe_end"]), (tp["windup_speed"], tp["swing_speed"])
        else:
            points, speeds = (tp["fe_start"], tp["fe_end"]), (tp["swing_speed"],)
        # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
        ramps = swing_ramps(first.ctrl, [e._rud for e in worlds], points, [s * limit for s in speeds],
                            tp["swing_start_s"], tp["windup_hold_s"], first.cfg["episode_s"])
        for e, (ts, fes) in zip(worlds, ramps):
            e._swing_t, e._swing_fe = ts, fes
            swing_t0 = tp["swing_start_s"]
            if first.windup:  # the forward swing starts where the reference leaves fe_back
                at_back = np.flatnonzero(fes <= tp["fe_back"])
                swing_t0 = float(ts[at_back[-1]]) if at_back.size else math.inf
            e._ep.task.put(0, swing_t0=swing_t0)

    def _fe_rate(self, fe: float, fraction: float | None = None) -> float:
        """FE rate (rad/s) at which the fastest-turning PM motor runs at ``fraction`` (default ``swing_speed``)
        x its speed limit (``ramp.fe_rate``)."""
        speed = (self.tp["swing_speed"] if fraction is None else fraction) * self.nominal_params.motor.speed_limit
        return fe_rate(self.ctrl, self._rud, speed)(fe)

    def _leg_rate(self, fe: float) -> float:
        """max over the legs of |d q1 / d FE| at (rud, fe): motor radians per radian of FE (rigid): ``leg_rate``."""
        return leg_rate(self.ctrl, self._rud, fe)

    def swing_direction(self, fe: float) -> np.ndarray:
        """Unit direction (base frame) in which the head centre moves as FE grows, at (rud, fe), rigid."""
        return self._swing_geometry([self], np.array([fe]))[1][0]

    def rigid_speed(self) -> float:
        """The rigid bound (m/s): the head's speed along the anvil normal at the strike posture when the link
        follows the motors rigidly along the swing, the fastest motor at its speed limit (x ``swing_speed``):
        speed limit x lever, the lever being the head's speed per radian of FE over the leg's."""
        return self._swing_geometry([self], np.array([self._fe_strike]))[0][0]

    @staticmethod
    def _swing_geometry(worlds: list, fe: np.ndarray) -> tuple[list, np.ndarray, np.ndarray]:
        """At FE angle fe[k] of each world k (its rud, PS and handle), rigid: the rigid bound (m/s, as
        ``rigid_speed``), the unit swing direction and the head centre (m, base frame), from the head's chord
        between fe - h and fe + h (h = 1e-5 rad); the analytic kinematics of all the postures in one pass."""
        h = 1e-5
        head = np.zeros((len(worlds), 3))
        head[:, 0] = [e._handle for e in worlds]
        plus, minus, at = worlds[0].chord_points(np.array([e._rud for e in worlds]), fe,
                                                 np.array([e._ps for e in worlds]), head, h)
        d = plus - minus
        nd = np.linalg.norm(d, axis=-1)
        rigid = [e._fe_rate(fk) * (ndk / (2 * h)) for e, fk, ndk in zip(worlds, fe.tolist(), nd.tolist())]
        return rigid, d / nd[:, None], at

    @classmethod
    def _strike_geometry(cls, worlds: list) -> None:
        """Each world's rigid bound, and the anvil's normal (the swing direction) and the nail (where the head's
        end face is) at its strike posture, for ``_after_reset``."""
        rigid, n, c = cls._swing_geometry(worlds, np.array([e._fe_strike for e in worlds]))
        face = c + (HEAD_HALF_LENGTH + worlds[0].tp["head_radius"]) * n
        for e, rk, nk, fk in zip(worlds, rigid, n, face):
            e._ep.task.put(0, rigid=rk, normal=nk, face=fk)

    def _after_reset(self) -> None:
        # the anvil's face (its +Z) meets the head's end face at the strike posture, facing the swing
        n, face = self._normal, self._face
        up = np.array([0.0, 0.0, 1.0])
        R = frame_from_z(-n, y_hint=up - (up @ n) * n)
        self.data.mocap_pos[self._mocap] = face
        self.data.mocap_quat[self._mocap] = quat_from_matrix(R)
        self._ep.task.put(0, t0=float(self.data.time))  # the episode's t = 0 (after the settling)

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.full_like(t, self._rud), np.interp(t, self._swing_t, self._swing_fe),
                         np.full_like(t, self._ps)], axis=-1)

    # ------------------------------------------------------------------ the strike, to the substep
    def _on_first_contact(self, time: float, pos: np.ndarray, vel: np.ndarray) -> None:
        # the first substep that finds the head on the anvil: its start (time is after it) and the head's
        # velocity there, before any contact force acted; read with the step's measures (its clock advanced)
        ts = self._ep.task
        if not ts.struck[0]:
            t = time - self._t0 - self.sim.timestep
            normal = self._normal
            speed = float(vel @ normal)
            off = pos - self._face
            off -= (off @ normal) * normal  # in the face's plane
            timely = t <= self._swing_t0 + self.tp["strike_deadline_s"]
            step = self._ep.step.item(0)
            ts.put(0, struck=True, strike_t=t, strike_speed=speed, strike_offset=float(np.linalg.norm(off)),
                   timely=timely, strike_step=step)
            if timely:  # paid on this step, and no miss
                ts.reward_terms[0, step, IMPACT] = speed / self.cfg["scales"]["speed"]
                ts.reward_terms[0, self.episode_steps, MISS] = 0.0

    # ------------------------------------------------------------------ reward and success
    def timely(self) -> bool:
        """Whether the head has struck the anvil, by the deadline after the forward swing began."""
        return self._ep.task.timely.item(0)

    def off_plane(self) -> float:
        """The largest RUD or PS error (rad) of the episode's steps so far, up to the strike's."""
        ep = self._ep
        return off_plane_errors(ep.history_error[:, :ep.step.item(0)], ep.task.strike_step[0:1]).item(0)

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err) -> dict:
        terms = at_step(ep, ids, ep.task.reward_terms)
        return {"impact": terms[:, IMPACT], "miss": terms[:, MISS]}

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        ts = ep.task
        err, _, _ = episode_history(ep, ids)
        return (ts.timely[ids] & (ts.strike_speed[ids] >= tp["success_speed_ratio"] * ts.rigid[ids])
                & (ts.strike_offset[ids] <= tp["success_radius"])
                & (off_plane_errors(err, ts.strike_step[ids]) <= tp["success_plane_error"]))

    @classmethod
    def _task_info_worlds(cls, worlds: list, ep, ids) -> dict:
        # no strike yet: struck False and zeros (no NaN in info: equal episodes must give equal infos)
        ts = ep.task
        return {"struck": ts.struck[ids], "impact_speed": ts.strike_speed[ids], "impact_time": ts.strike_t[ids],
                "impact_offset": ts.strike_offset[ids], "rigid_speed": ts.rigid[ids]}

    def __setstate__(self, state):
        super().__setstate__(state)
        if self._handle > 0.0:  # the episode's handle length (the rebuilt model has the nominal one; 0: no episode)
            self.model.body_pos[self._head_body] = (self._handle, 0.0, 0.0)


def off_plane_errors(err, strike_step) -> np.ndarray:
    """How far RUD and PS left the swing's plane until the strike (L,) (rad), from posture errors ``err`` (L, k, 3)
    of each world's steps 1 ... k, up to step ``strike_step`` (the strike's, included; 0: no strike, all k)."""
    k = err.shape[1]
    return off_plane(err, np.where(strike_step > 0, strike_step, k))
