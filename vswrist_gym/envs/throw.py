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
a control period is one ``mj_step`` call; in between it runs substep by substep to find the release to the
millisecond, so a batch steps these worlds world by world on its threads (``batch.VSWristVectorEnv``: the compiled advance needs the
base's ``_advance_physics``).
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from .base import VSWristEnv
from .hammer import ramp_through

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
        from .observations import ObsTerm
        return [ObsTerm("released", 1, "-", "1 once the ball has left the hand, else 0 (no sensor noise)",
                        lambda: np.array([1.0 if self._release is not None else 0.0]), 0.0, 1.0)]

    # ------------------------------------------------------------------ episode
    def _task_reset(self, rng):
        tp = self.tp
        self._ball_mass = float(rng.uniform(*tp["ball_mass"]))
        self._ball_L = float(rng.uniform(*tp["ball_distance"]))
        self._rud = float(rng.uniform(*tp["rud_range"]))
        self._fe_release = float(rng.uniform(*tp["fe_release"]))
        self._ps = 0.0
        self._set_ball(self._ball_mass)
        self._release = None       # (time s, speed m/s, aim error rad, distance m) of the release
        self._release_seen = False  # whether the step that saw the release has paid it
        self._mass_due = False      # the ball has left: its mass leaves the hand at the next substep boundary
        return np.array([self._rud, tp["fe_start"]]), self._ps, -1.0

    def _set_ball(self, mass: float) -> None:
        """The ball's mass and inertia (solid sphere) and place, in place (no recompilation)."""
        m = self.model
        m.body_pos[self._ball_body] = (self._ball_L, 0.0, 0.0)
        m.body_mass[self._ball_body] = mass
        m.body_inertia[self._ball_body] = 0.4 * mass * self.tp["ball_radius"] ** 2

    @classmethod
    def _reset_worlds(cls, worlds: list) -> None:
        """Each world's counter-movement (``ramp_through``) and its release geometry, world by world (a few
        milliseconds of Python per reset, about a tenth of an episode's physics)."""
        for e in worlds:
            tp = e.tp
            back = lambda fe, e=e: e._fe_rate(fe, tp["windup_speed"])  # noqa: E731
            fwd = lambda fe, e=e: e._fe_rate(fe, tp["swing_speed"])  # noqa: E731
            e._ref_t, e._ref_fe = ramp_through((tp["fe_start"], tp["fe_back"], tp["fe_end"]), (back, fwd),
                                               tp["windup_start_s"], tp["windup_hold_s"], e.cfg["episode_s"])
            # the forward swing starts where the reference leaves fe_back
            at_back = np.flatnonzero(e._ref_fe <= tp["fe_back"])
            e._swing_t0 = float(e._ref_t[at_back[-1]]) if at_back.size else math.inf
            e._rigid, e._dir, e._c = e._swing_geometry(e._fe_release)
            d2 = e._swing_geometry(e._fe_release + 0.1)[1]
            n = np.cross(e._dir, d2)
            e._normal = n / np.linalg.norm(n)  # the swing plane's normal

    def _fe_rate(self, fe: float, fraction: float) -> float:
        """FE rate (rad/s) at which the fastest-turning PM motor runs at ``fraction`` x its speed limit."""
        _, Ja = self.ctrl._q1_ja(self._rud, fe)
        lever = max(abs(Ja[0][1]), abs(Ja[1][1]), abs(Ja[2][1]))
        return fraction * self.nominal_params.motor.speed_limit / lever

    def _swing_geometry(self, fe: float) -> tuple[float, np.ndarray, np.ndarray]:
        """At FE ``fe`` (this episode's RUD, PS and ball), rigid: the rigid bound (m/s: the ball's speed when the
        fastest motor runs at ``swing_speed`` x its limit), the unit direction in which the ball moves as FE grows
        and the ball's centre (m, base frame), from the chord between fe - h and fe + h (h = 1e-5 rad)."""
        h = 1e-5
        u = np.array([[self._rud, fe + h], [self._rud, fe - h], [self._rud, fe]])
        p = self.tool_point(u, np.full(3, self._ps), np.tile([self._ball_L, 0.0, 0.0], (3, 1)))
        d = p[0] - p[1]
        nd = float(np.linalg.norm(d))
        return self._fe_rate(fe, self.tp["swing_speed"]) * nd / (2 * h), d / nd, p[2]

    def _reference(self, t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        return np.stack([np.full_like(t, self._rud), np.interp(t, self._ref_t, self._ref_fe),
                         np.full_like(t, self._ps)], axis=-1)

    def _after_reset(self) -> None:
        self._t0 = float(self.data.time)  # the episode's t = 0 (after the settling)

    # ------------------------------------------------------------------ the release, to the substep
    def _behind(self) -> float:
        """How far (m) the ball's centre is behind the release plane (negative: past it), from ``data.xpos``."""
        return float((self._c - self.data.xpos[self._ball_body]) @ self._dir)

    def _advance_physics(self, duration: float, first: bool) -> None:
        if self._release is not None and not self._mass_due:
            self.sim.step(duration, restart_peak=first)
            return
        if self._release is None and not self._passed:
            # the release waits for the forward swing and for the ball to be behind the plane (the wind-up may
            # start past it, and a soft wrist may lag the wind-up's turn)
            if self._t < self._swing_t0 - 1e-9:
                self.sim.step(duration, restart_peak=first)
                return
            self.sim.sync_kinematics()  # xpos of the state this period starts from
            behind = self._behind()
            self._armed = self._armed or behind > 0.0
            if behind > RELEASE_REACH:
                self.sim.step(duration, restart_peak=first)
                return
        # after mj_step(m, d, 1), xpos and the body velocities are those of the state the substep started from
        m, d = self.model, self.data
        dt = self.sim.timestep
        for k in range(int(round(duration / dt))):
            if self._mass_due:  # the substep boundary after the one that recognised the peak: the ball has gone
                self._mass_due = False
                self._set_ball(MASS_GONE)
            self.sim.step(dt, restart_peak=first and k == 0)
            if self._release is None:
                self._read_substep(float(d.time) - dt)

    def _read_substep(self, time: float) -> None:
        """One state of the forward swing (``time``: its data.time): arm, pass the plane, or release at the peak."""
        behind = self._behind()
        if not self._passed:
            if self._armed and behind <= 0.0:
                self._passed = True
            else:
                self._armed = self._armed or behind > 0.0
                return
        mujoco.mj_objectVelocity(self.model, self.data, mujoco.mjtObj.mjOBJ_BODY, self._ball_body, self._vel6, 0)
        vel = self._vel6[3:].copy()
        speed = float(np.linalg.norm(vel))
        if self._peak is not None and speed < self._peak[1]:
            self._on_release(self._peak[0], self._peak[2])
        else:
            self._peak = (time, speed, vel)

    def _on_release(self, time: float, vel: np.ndarray) -> None:
        speed = float(np.linalg.norm(vel))
        # out of the swing plane (the throw's plane): the angle between the velocity and the plane
        aim = math.asin(min(1.0, abs(float(vel @ self._normal)) / speed)) if speed > 0.0 else math.pi / 2
        self._release = (time - self._t0, speed, aim, self._distance(vel))
        self._mass_due = True

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
        return self._release is not None and \
            self._release[0] <= self._swing_t0 + self.tp["release_deadline_s"]

    def _task_reward_terms(self, err) -> dict:
        if self._release is None:  # until the release: how far RUD and PS left the swing's plane
            self._off_plane = max(self._off_plane, abs(float(err[0])), abs(float(err[2])))
        throw = 0.0
        if self._release is not None and not self._release_seen:
            self._release_seen = True
            throw = self._release[1] / self.cfg["scales"]["speed"] if self.timely() else 0.0
        last = self._step >= self.episode_steps
        return {"throw": throw, "miss": -1.0 if last and not self.timely() else 0.0}

    def _success(self) -> bool:
        return self.timely() and self._release[1] >= self.tp["success_speed_ratio"] * self._rigid and \
            self._release[2] <= self.tp["success_aim_error"] and self._off_plane <= self.tp["success_plane_error"]

    def _task_info(self) -> dict:
        # no release yet: released False and zeros (no NaN in info: equal episodes must give equal infos)
        r = getattr(self, "_release", None)
        return {"released": r is not None, "release_speed": 0.0 if r is None else r[1],
                "release_time": 0.0 if r is None else r[0], "aim_error": 0.0 if r is None else r[2],
                "throw_distance": 0.0 if r is None else r[3], "rigid_speed": float(getattr(self, "_rigid", 0.0))}

    def __setstate__(self, state):
        super().__setstate__(state)
        if hasattr(self, "_ball_L"):  # the episode's ball distance (the rebuilt model has the nominal one)
            self.model.body_pos[self._ball_body] = (self._ball_L, 0.0, 0.0)

    def _reset_state(self) -> None:
        super()._reset_state()
        self._release = None
        self._release_seen = False
        self._mass_due = False
        self._armed = False  # the ball has been seen behind the release plane in the forward swing
        self._passed = False  # ... and then past it: the release comes at its next speed peak
        self._peak = None     # (time s, speed m/s, velocity) of the fastest state since it passed
        self._t0 = 0.0
        self._off_plane = 0.0  # rad, largest RUD or PS error before the release
