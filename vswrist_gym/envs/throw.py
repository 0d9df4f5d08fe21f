"""``VSWrist/Throw-v0``: wind up and throw a ball as fast as the springs allow, the motors speed-limited.

After Braun, Howard and Vijayakumar, "Optimal variable stiffness control: formulation and application to explosive
movement tasks" (Autonomous Robots 2012): a speed-limited motor in series with a spring throws farther than the
motor alone, because the spring stores energy during a wind-up and gives it back, and how much it stores and
returns depends on the stiffness over time.

The tool is a light handle with a ball (a solid sphere of mass ``ball_mass`` at ``ball_distance`` from the hand
along the tool X axis, both drawn per episode) held in the hand. The posture reference is fixed, a counter-movement
in FE at a fixed RUD (``rud_range``) and PS = 0: from ``fe_start`` at ``windup_start_s`` it winds back to
``fe_back``, the fastest PM motor at ``windup_speed`` x its speed limit (``motor.speed_limit`` of the device
preset), holds there ``windup_hold_s``, then swings forward to ``fe_end`` with the fastest motor at its speed limit
(``swing_speed`` x). Gravity (along -Z_b) is across the swing, which moves the ball horizontally.

The hand lets the ball go automatically, as a thrower's hand does at the fastest point of the arm's swing: once the
ball's centre has passed the *release plane* in the forward swing (the plane through the ball's centre at FE =
``fe_release``, drawn per episode, perpendicular to its path there), at the first substep (1 ms) at which the
ball's speed stops rising; the release state is the fastest one. The ball then flies free: its flight is a
closed-form projectile (no contact, no drag); its mass leaves the hand at the substep boundary after the peak is
recognised (2 ms after the release state). ``info`` holds
``released``, ``release_speed`` (m/s, the ball's speed at release), ``release_time`` (s), ``aim_error`` (rad, the
angle between the ball's velocity and the swing's plane, the plane the throw is aimed in), ``throw_distance`` (m,
how far the ball lands horizontally, ``drop_height`` below the release point) and ``rigid_speed`` (m/s, the *rigid
bound*: the ball's speed at the release plane's posture when the link follows the motors rigidly, the fastest at its
speed limit: speed limit x lever), zeros before a release.

The agent sets the stiffness (the internal torque ``lam`` of the PM motors in ker(J_a^T)); the posture channel may
be ignored (``residual`` mode with ``posture_scale: 0`` is the stiffness track). Soft while the wind-up turns
round lets the link lag the motors and load the springs; stiff while they release returns the energy with a
larger torque (the motors do work on the springs as they raise the preload while deflected).

Reward: on the step the release is seen, the release speed (``throw``, m/s / ``scales.speed``); ``miss`` -1 on
the last step if no release came by ``release_deadline_s`` after the forward swing began (a late release earns no
``throw`` either); preload energy at a small weight. Success: a timely release at a speed >= ``success_speed_ratio``
x the rigid bound, aimed within ``success_aim_error`` of the swing's plane, RUD and PS within
``success_plane_error`` of the swing's until the release: a throw, not a flail.

Cost: until the release is near (the ball within ``RELEASE_REACH`` of the plane in the forward swing) and after it,
a control period is one ``mj_step`` call (``_plain_period``); in between it runs substep by substep to find the
release to the millisecond (``_advance_physics``). A batch runs both in its compiled advance, on its physics
threads: each world's release watch (``_watch_worlds``: a row of its task state, in the layout of
``batch_sim.watch_rows``) does there what ``_advance_physics`` does here, and ``_after_watch_worlds`` writes the
release into the task state (``task_state``) as ``_on_release`` does. The reward terms, info, success and the
``released`` observation term are written over arrays of worlds (``hooks``): a batch computes them once for all its
worlds. The reward terms are a table over the episode's control steps, written at reset and by the release, so that
a step reads its row; the RUD and PS errors before the release come from the episode's posture-error history at its
end.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from ..batch_sim import read_watch, watch_rows
from .base import VSWristEnv
from .episode import at_step, episode_history, task_field
from .ramp import fe_rates, swing_ramps
from .shared import off_plane

NOMINAL_BALL_MASS = 0.15   # kg, compiled in the model; each episode sets its own mass in place
HANDLE_START = 0.02        # m, the handle starts this far from the hand along the tool X axis
# m: while the ball is farther than this behind the release plane at a period's start, the period cannot reach it
# (25 m/s for 10 ms, about three times the fastest throws) and runs as one mj_step call
RELEASE_REACH = 0.25
MASS_GONE = 1e-9           # kg: the ball's mass once it has left the hand (MuJoCo keeps the massless body welded)


class ThrowEnv(VSWristEnv):
    task = "throw"
    task_id = "VSWrist/Throw-v0"
    summary = ("wind up and throw a ball (random mass, distance from the hand and release point) through a fixed, "
               "motor-speed-limited FE counter-movement as fast as possible")
    success_text = ("a release within {release_deadline_s:g} s of the forward swing's start at a speed "
                    ">= {success_speed_ratio:g} x the rigid bound (motor speed limit x lever), aimed within "
                    "{success_aim_error:g} rad of the swing's plane, RUD and PS within {success_plane_error:g} rad of "
                    "the swing's until then")
    task_spec = {
        "ball_mass": ("interval", 0.001, 2.0),
        "ball_distance": ("interval", 0.06, 0.4),
        "ball_radius": ("number", 0.003, 0.05),
        "handle_mass": ("number", 0.001, 1.0),
        "handle_radius": ("number", 0.001, 0.03),
        "rud_range": ("interval", -0.8, 0.8),
        "fe_start": ("number", -0.78, 0.95),
        "fe_back": ("number", -0.78, 0.95),
        "fe_release": ("interval", -0.78, 0.95),
        "fe_end": ("number", -0.78, 0.95),
        "windup_start_s": ("number", 0.0, 600.0),
        "windup_speed": ("number", 0.01, 1.0),
        "windup_hold_s": ("number", 0.0, 10.0),
        "swing_speed": ("number", 0.01, 1.0),
        "release_deadline_s": ("number", 0.0, 600.0),
        "drop_height": ("number", 0.0, 100.0),
        "success_speed_ratio": ("number", 0.0, 100.0),
        "success_aim_error": ("number", 0.0, 3.2),
        "success_plane_error": ("number", 0.0, 10.0),
    }
    task_reward_terms = ("throw", "miss")
    reads_sensors = False  # the release reads body poses and velocities only
    PS = 0.0  # rad, the PS reference: the throw is in FE

    @property
    def task_state(self) -> dict:
        """The episode's draws: the ball (``ball_mass``, kg; ``ball_L``, m from the hand along the tool X axis), the
        throw's ``rud`` (rad) and ``fe_release`` (rad, the release plane's FE); the swing's geometry
        (``_reset_worlds``): ``swing_t0`` (s, the forward swing's start), the rigid bound ``rigid`` (m/s), the ball's
        unit direction of motion ``dir`` and its centre ``c`` (m, base frame) at the release plane's posture, the
        swing plane's unit ``normal``; ``t0`` (s, the simulator's time at the episode's t = 0).

        The release, found substep by substep (on a batch's physics threads, each world writing its own row): the
        ball seen behind the release plane in the forward swing (``armed``), then past it (``passed``); the fastest
        state since (``peak_time``, s of data.time; ``peak_speed``, m/s, 0 before; ``peak_vel``, m/s); the release
        (``released``; ``release_time``, s; ``release_speed``, m/s; ``aim``, rad off the swing plane; ``distance``,
        m; ``timely``: by the deadline; ``release_step``: the steps taken before the period it came in); whether its
        mass is still to leave the hand at the next substep boundary (``mass_due``). The reward terms (``terms``:
        throw and miss at each control step, a table over the episode's control instants as the posture references):
        the miss at the last step, written at reset, cleared by a timely release, which writes its throw at its
        period's step.

        The reference's ramp (``_ref_t``, ``_ref_fe``) stays on the world: its length varies with the episode (the
        ramp's integration points), and the steps read the posture references the reset computed from it."""
        return {"ball_mass": ((), float), "ball_L": ((), float), "rud": ((), float), "fe_release": ((), float),
                "swing_t0": ((), float), "rigid": ((), float), "dir": ((3,), float), "c": ((3,), float),
                "normal": ((3,), float), "t0": ((), float),
                "armed": ((), bool), "passed": ((), bool), "peak_time": ((), float), "peak_speed": ((), float),
                "peak_vel": ((3,), float),
                "released": ((), bool), "release_time": ((), float), "release_speed": ((), float), "aim": ((), float),
                "distance": ((), float), "timely": ((), bool), "release_step": ((), np.int64), "mass_due": ((), bool),
                "terms": ((self.episode_steps + 1, 2), float)}

    _ball_mass, _ball_L, _rud, _fe_release, _swing_t0, _rigid, _dir, _c, _normal, _t0, _peak_vel = map(
        task_field, ("ball_mass", "ball_L", "rud", "fe_release", "swing_t0", "rigid", "dir", "c", "normal", "t0",
                     "peak_vel"))

    def _validate_task(self) -> None:
        from .config import EnvConfigError
        tp = self.tp
        if not (tp["fe_back"] < tp["fe_start"] and tp["fe_back"] < tp["fe_release"][0] and
                tp["fe_release"][1] < tp["fe_end"]):
            raise EnvConfigError(f"'task.fe_back' < 'task.fe_start' and 'task.fe_back' < 'task.fe_release' < "
                                 f"'task.fe_end' are required (a wind-up, then a swing through the release), got "
                                 f"{tp['fe_back']:g}, {tp['fe_start']:g}, {list(tp['fe_release'])}, {tp['fe_end']:g}")

    # ------------------------------------------------------------------ scene
    def _scene(self, spec) -> None:
        tp = self.tp
        L = 0.5 * (tp["ball_distance"][0] + tp["ball_distance"][1])
        # nothing collides: the throw is free motion, and the ball's flight is computed in closed form
        spec.body("tool").add_geom(name="throw_handle", type=mujoco.mjtGeom.mjGEOM_CAPSULE,
                                   fromto=[HANDLE_START, 0, 0, L, 0, 0], size=[tp["handle_radius"], 0, 0],
                                   mass=tp["handle_mass"], contype=0, conaffinity=0, rgba=[0.55, 0.4, 0.25, 1],
                                   group=1)
        ball = spec.body("tool").add_body(name="throw_ball", pos=[L, 0, 0])
        ball.add_geom(name="throw_ball", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[tp["ball_radius"], 0, 0],
                      mass=NOMINAL_BALL_MASS, contype=0, conaffinity=0, rgba=[0.85, 0.3, 0.2, 1], group=1)

    def _scene_ids(self) -> None:
        m = self.model
        self._ball_body = int(m.body("throw_ball").id)
        self._ball_geom = int(m.geom("throw_ball").id)
        self._vel6 = np.zeros(6)

    def _task_obs_terms(self):
        from .observations import ObsTerm, column
        return [ObsTerm("released", 1, "-", "1 once the ball has left the hand, else 0 (no sensor noise)", None,
                        0.0, 1.0, lambda m: column(m.state("released")))]

    # ------------------------------------------------------------------ episode
    def _task_reset(self, rng):
        tp = self.tp
        mass = float(rng.uniform(*tp["ball_mass"]))
        L = float(rng.uniform(*tp["ball_distance"]))
        rud = float(rng.uniform(*tp["rud_range"]))
        fe_release = float(rng.uniform(*tp["fe_release"]))
        st = self._ep.task
        st.put(0, ball_mass=mass, ball_L=L, rud=rud, fe_release=fe_release)
        st.terms[0, -1, 1] = -1.0  # a miss, unless a timely release comes
        self._set_ball(mass)
        return np.array([rud, tp["fe_start"]]), self.PS, -1.0

    def _set_ball(self, mass: float) -> None:
        """The ball's mass and inertia (solid sphere) and place, in place (no recompilation)."""
        m = self.model
        m.body_pos[self._ball_body] = (self._ball_L, 0.0, 0.0)
        m.body_mass[self._ball_body] = mass
        m.body_inertia[self._ball_body] = 0.4 * mass * self.tp["ball_radius"] ** 2

    @classmethod
    def _reset_worlds(cls, worlds: list) -> None:
        """Each world's counter-movement (``ramp.swing_ramps``: over arrays for many worlds at once) and its release
        geometry."""
        first = worlds[0]
        tp = first.tp
        limit = first.nominal_params.motor.speed_limit
        # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
        ramps = swing_ramps(first.ctrl, [e._rud for e in worlds], (tp["fe_start"], tp["fe_back"], tp["fe_end"]),
                            (tp["windup_speed"] * limit, tp["swing_speed"] * limit), tp["windup_start_s"],
                            tp["windup_hold_s"], first.cfg["episode_s"])
        fe = np.array([e._fe_release for e in worlds])
        rigid, d, c = cls._swing_geometry(worlds, fe)
        _, d_on, _ = cls._swing_geometry(worlds, fe + 0.1)
        for k, (e, (ts, fes)) in enumerate(zip(worlds, ramps)):
            e._ref_t, e._ref_fe = ts, fes
            # the forward swing starts where the reference leaves fe_back
            at_back = np.flatnonzero(fes <= tp["fe_back"])
            swing_t0 = float(ts[at_back[-1]]) if at_back.size else math.inf
            n = np.cross(d[k], d_on[k])
            e._ep.task.put(0, swing_t0=swing_t0, rigid=rigid[k], dir=d[k], c=c[k], normal=n / np.linalg.norm(n))

    @staticmethod
    def _swing_geometry(worlds: list, fe: np.ndarray) -> tuple[list, list, list]:
        """At FEs ``fe`` (L,) (each world's RUD, PS and ball), rigid: the rigid bound (m/s: the ball's speed when the
        fastest motor runs at ``swing_speed`` x its limit), the unit direction in which the ball moves as FE grows
        and the ball's centre (m, base frame), from the chord between fe - h and fe + h (h = 1e-5 rad); the
        kinematics over arrays of worlds (each row as alone), each world's norms on its own."""
        first = worlds[0]
        L, h = len(worlds), 1e-5
        rud = np.array([e._rud for e in worlds])
        ball = np.zeros((L, 3))
        ball[:, 0] = [e._ball_L for e in worlds]
        plus, minus, at = first.chord_points(rud, fe, np.full(L, first.PS), ball, h)
        # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
        rates = fe_rates(first.ctrl, rud, first.tp["swing_speed"] * first.nominal_params.motor.speed_limit)(
            fe, np.arange(L)).tolist()
        rigid, direction = [], []
        for k in range(L):
            d = plus[k] - minus[k]
            nd = float(np.linalg.norm(d))
            rigid.append(rates[k] * nd / (2 * h))
            direction.append(d / nd)
        return rigid, direction, list(at)

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.full_like(t, self._rud), np.interp(t, self._ref_t, self._ref_fe),
                         np.full_like(t, self.PS)], axis=-1)

    def _after_reset(self) -> None:
        self._ep.task.t0[0] = self.data.time  # the episode's t = 0 (after the settling)

    # ------------------------------------------------------------------ the release, to the substep
    # The single env's search (and the reference physics'); a batch's compiled advance runs the same in its watch.
    def _behind(self, c: np.ndarray, direction: np.ndarray) -> float:
        """How far (m) the ball's centre is behind the release plane (negative: past it), from ``data.xpos``: ``c``
        and ``direction`` are this world's ``c`` and ``dir`` (rows of the task state)."""
        return float((c - self.data.xpos[self._ball_body]) @ direction)

    def _plain_period(self) -> bool:
        """Whether the coming period (or part of one) is plain physics, one ``mj_step`` call: after the release
        (once the ball's mass has gone), before the forward swing, or while the ball is farther than
        ``RELEASE_REACH`` behind the release plane at its start, where it arms the release once it sees the ball
        behind the plane (the wind-up may start past it, and a soft wrist may lag the wind-up's turn)."""
        st = self._ep.task
        released = st.released.item(0)
        if released and not st.mass_due.item(0):
            return True
        if self._t < st.swing_t0.item(0) - 1e-9:  # nothing of the release happens before the forward swing
            return True
        if not released and not st.passed.item(0):
            self.sim.sync_kinematics()  # xpos of the state this period starts from
            behind = self._behind(st.c[0], st.dir[0])
            if not st.armed.item(0) and behind > 0.0:
                st.armed[0] = True
            if behind > RELEASE_REACH:
                return True
        return False

    @classmethod
    def _watch_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        st = ep.task
        first = worlds[0]
        gone = 0.4 * MASS_GONE * first.tp["ball_radius"] ** 2  # _set_ball's inertia of MASS_GONE, to the bit
        return watch_rows(st.c[ids], st.dir[ids], st.armed[ids], st.passed[ids], st.released[ids], st.mass_due[ids],
                          st.peak_time[ids], st.peak_speed[ids], st.peak_vel[ids],
                          ~(ep.t[ids] < st.swing_t0[ids] - 1e-9), first._ball_body, MASS_GONE, gone, RELEASE_REACH)

    @classmethod
    def _after_watch_worlds(cls, worlds: list, ep, ids, rows: np.ndarray) -> None:
        st = ep.task
        w = read_watch(rows)
        st.put(ids, peak_time=w["peak_time"], peak_speed=w["peak_speed"], peak_vel=w["peak_vel"])
        # the release's record first (``_on_release`` marks its mass due, which a later substep may have cleared)
        for k in np.flatnonzero(w["released"] & ~st.released[ids]).tolist():
            e = worlds[k]
            e._on_release(e._ep.task, float(w["peak_time"][k]), w["peak_vel"][k].copy())
        st.put(ids, armed=w["armed"], passed=w["passed"], released=w["released"], mass_due=w["due"])

    def _advance_physics(self, duration: float, first: bool) -> None:
        if self._plain_period():
            self.sim.step(duration, restart_peak=first)
            return
        st = self._ep.task
        released, due, armed, passed = (st.released.item(0), st.mass_due.item(0), st.armed.item(0),
                                        st.passed.item(0))
        c, direction = st.c[0], st.dir[0]
        # substep by substep: arm, pass the plane, release at the speed's peak. After mj_step(m, d, 1), xpos and
        # the body velocities are those of the state the substep started from
        d = self.data
        dt = self.sim.timestep
        for k in range(int(round(duration / dt))):
            if due:  # the substep boundary after the one that recognised the peak: the ball has gone
                due = False
                st.mass_due[0] = False
                self._set_ball(MASS_GONE)
            self.sim.step(dt, restart_peak=first and k == 0)
            if released:
                continue
            behind = self._behind(c, direction)
            if not passed:
                if armed and behind <= 0.0:
                    passed = True
                    st.passed[0] = True
                else:
                    if not armed and behind > 0.0:
                        armed = True
                        st.armed[0] = True
                    continue
            released = due = self._at_peak(st, float(d.time) - dt)

    def _at_peak(self, st, time: float) -> bool:
        """A state of the forward swing past the release plane (``time``: its data.time; ``st``: this world's task
        state): the fastest yet, or the first slower one, which releases the ball at the peak (returns whether)."""
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, self._ball_body, self._vel6, 0)
        vel = self._vel6[3:].copy()
        speed = float(np.linalg.norm(vel))
        if speed < st.peak_speed.item(0):  # slower than the peak (none yet: 0, and a speed is never below it)
            self._on_release(st, st.peak_time.item(0), st.peak_vel[0])
            return True
        st.peak_time[0] = time
        st.peak_speed[0] = speed
        st.peak_vel[0] = vel
        return False

    def _on_release(self, st, time: float, vel: np.ndarray) -> None:
        speed = float(np.linalg.norm(vel))
        # out of the swing plane (the throw's plane): the angle between the velocity and the plane
        aim = math.asin(min(1.0, abs(float(vel @ st.normal[0])) / speed)) if speed > 0.0 else math.pi / 2
        t = time - st.t0.item(0)
        st.release_time[0] = t
        st.release_speed[0] = speed
        st.aim[0] = aim
        st.distance[0] = self._distance(vel)
        # the steps taken before this period are those before the release (``off_plane``); the period's own step
        # (counted once the physics is over) pays the throw, if timely (a late release earns nothing)
        k = self._ep.step.item(0)
        st.release_step[0] = k
        if t <= st.swing_t0.item(0) + self.tp["release_deadline_s"]:
            st.timely[0] = True
            st.terms[0, k + 1, 0] = speed / self.cfg["scales"]["speed"]
            st.terms[0, -1, 1] = 0.0  # no miss
        st.released[0] = True
        st.mass_due[0] = True

    def _distance(self, vel: np.ndarray) -> float:
        """How far (m, horizontally) a projectile with velocity ``vel`` (m/s) from the release point lands
        ``drop_height`` below it (gravity along -Z_b, no drag): horizontal speed x fall time."""
        g = float(-self.model.opt.gravity[2])
        vz, h = float(vel[2]), self.tp["drop_height"]
        t_fall = (vz + math.sqrt(vz * vz + 2.0 * g * h)) / g
        return math.hypot(float(vel[0]), float(vel[1])) * t_fall

    # ------------------------------------------------------------------ reward and success
    def timely(self) -> bool:
        """Whether the ball has been released, by the deadline after the forward swing began."""
        return self._ep.task.timely.item(0)

    @classmethod
    def _task_reward_terms_worlds(cls, worlds: list, ep, ids, err) -> dict:
        terms = at_step(ep, ids, ep.task.terms)
        return {"throw": terms[:, 0], "miss": terms[:, 1]}

    @classmethod
    def _success_worlds(cls, worlds: list, ep, ids) -> np.ndarray:
        tp = worlds[0].tp
        st = ep.task
        err, _, _ = episode_history(ep, ids)
        return (st.timely[ids] & (st.release_speed[ids] >= tp["success_speed_ratio"] * st.rigid[ids])
                & (st.aim[ids] <= tp["success_aim_error"])
                & (off_plane(err, st.release_step[ids]) <= tp["success_plane_error"]))

    @classmethod
    def _task_info_worlds(cls, worlds: list, ep, ids) -> dict:
        # before a release: released False and zeros, the cleared state (no NaN in info: equal episodes must give
        # equal infos)
        st = ep.task
        return {"released": st.released[ids], "release_speed": st.release_speed[ids],
                "release_time": st.release_time[ids], "aim_error": st.aim[ids], "throw_distance": st.distance[ids],
                "rigid_speed": st.rigid[ids]}

    def __setstate__(self, state):
        super().__setstate__(state)
        if self._ball_L > 0.0:  # the episode's ball distance (the rebuilt model has the nominal one; 0: none drawn)
            self.model.body_pos[self._ball_body] = (self._ball_L, 0.0, 0.0)

