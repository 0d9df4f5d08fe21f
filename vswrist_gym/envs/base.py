"""The VS-Wrist base environment: ``WristSim`` + ``AnalyticController`` behind a Gymnasium interface.

Time is in seconds: the control period ``ctrl_dt`` (default 0.02 s, 50 Hz) must be a whole number of physics
steps (``physics_dt``, default the simulator's), checked at construction. One ``step``:

1. the action is checked (exactly the action space's shape, real numbers, no NaN or inf; else ``ValueError``)
   and clipped to [-1, 1]; a step after the episode ended (or before the first ``reset``) raises
   ``gymnasium.error.ResetNeeded``;
2. the action mode turns it into motor references (via the analytic controller, except mode ``motor``);
3. the task applies its external loads (wrenches on the hand, obstacles are in the model);
4. the simulator advances ``ctrl_dt`` (springs and motors every substep); with ``latency`` randomisation the
   previous references are held for the first part of the period;
5. observation, unweighted reward terms, weights from config, metrics, and the physics' validity: the worst
   loop-closure opening over the period's substeps (``info["loop_closure"]``), flagged past ``closure_warn``.

Contract (used by the agents): ``obs_slices`` (term -> slice of the flat observation, ``target`` = posture
reference (RUD, FE, PS), rad), ``reference_to_action(posture_ref, stiffness)`` (the inverse of the
``posture_stiffness`` mapping), ``info`` with every weighted term ``reward_<name>`` (summing exactly to the
reward) and the metrics ``posture_error`` (rad), ``contact_force`` (N), ``peak_contact_force`` (N),
``rms_contact_force`` (N), ``elastic_energy`` (J), ``lam`` (N m), ``loop_closure`` (m or rad, the largest weld
violation at the start of the period and after each of its substeps, ``WristSim.loop_closure_peak``; inf on a
step where the physics diverged), ``closure_exceeded`` (``loop_closure > closure_warn``), ``is_success`` (bool,
decided at the last step of the episode; False before, and False when ``closure_truncate`` cut the episode).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from ..params import load_params
from .config import SCALE_TERMS, EnvConfigError, load_env_config, validate_task
from ._contact import CONTACT_SOLREF
from .spaces import ObsTerm, PostureMap, StiffnessMap, check_action, wrap_angle

DEVICE_TERMS = ("spring_K", "spring_delta0", "motor_time_constant", "link_mass", "hand_mass", "damping")
COMMON_REWARD_TERMS = ("tracking", "energy", "action_rate", "termination")
FORCE_CAP = 10.0  # force penalties saturate at FORCE_CAP x scales.force: one violent contact sample (rigid
                  # contacts driven by stiff servos reach kN for a step) must not swamp a whole episode


def _import_sim():
    try:
        from ..sim import WristSim
    except ImportError as exc:  # the simulator module is part of the package; say so if it is missing
        raise ImportError(f"vswrist_gym.sim.WristSim is required by the environments: {exc}") from exc
    return WristSim


def _import_controller():
    try:
        from ..control import AnalyticController
    except ImportError as exc:
        raise ImportError(f"vswrist_gym.control.AnalyticController is required by the environments: {exc}") from exc
    return AnalyticController


def _sum_sq(x: np.ndarray) -> float:
    """float(np.sum(x ** 2)) for the short vectors of the reward (numpy sums fewer than 8 terms in order)."""
    s = 0.0
    for v in (x * x).tolist():
        s += v
    return s


class VSWristEnv(gym.Env):
    """Base class of every VS-Wrist task (do not instantiate directly; use ``gymnasium.make``).

    Subclasses set ``task`` (the config file stem), ``task_spec`` (validation of the ``task`` section),
    ``task_reward_terms`` and implement ``_scene``, ``_task_reset``, ``_reference``, ``_task_reward_terms``,
    ``_success``; optionally ``_before_physics``, ``_contact_force``, ``_task_obs_terms``.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 50}
    task: str = ""
    task_id: str = ""
    summary: str = ""
    success_text: str = ""
    task_spec: dict[str, tuple] = {}
    task_reward_terms: tuple[str, ...] = ()
    # whether the task reads the simulator's sensors or forces (touch, wrench, contacts) after a step; tasks
    # that read only poses and velocities set False, and then (unless the observation has ``tool_wrench``)
    # each step updates only those (``WristSim.sync_kinematics``) instead of a full ``mj_forward``
    reads_sensors: bool = True

    # ------------------------------------------------------------------ spec
    _spec = None

    @property
    def spec(self):
        """The registration spec, with ``max_episode_steps`` = the episode length in steps: the env truncates its
        own episodes (config ``episode_s``), and libraries read the length here. ``gymnasium.make`` hands the
        unwrapped env a spec without one (its TimeLimit wrapper, absent here, would carry it)."""
        return self._spec

    @spec.setter
    def spec(self, value) -> None:
        if value is not None and value.max_episode_steps is None:
            value = dataclasses.replace(value, max_episode_steps=self.episode_steps)
        self._spec = value

    # ------------------------------------------------------------------ construction
    def __init__(self, render_mode: str | None = None, config: Mapping[str, Any] | None = None, **overrides: Any):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        if config is not None and not isinstance(config, Mapping):
            raise EnvConfigError(f"'config' must be a mapping of settings (e.g. {{'reward': {{'energy': 0.5}}}}), "
                                 f"got {type(config).__name__} {config!r}")
        user = dict(config or {})
        user.update(overrides)
        self._user_config = user
        cfg = load_env_config(self.task, user)
        self.cfg = cfg
        self.tp = validate_task(cfg["task"], self.task_spec, self.task)
        self.render_mode = render_mode
        self.nominal_params = load_params(cfg["params"])
        self._validate_task()
        self.params = self.nominal_params
        self.ctrl_dt = cfg["ctrl_dt"]
        self._closure_warn, self._closure_truncate = cfg["closure_warn"], cfg["closure_truncate"]
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.ctrl_dt)))

        self._WristSim = _import_sim()
        from ..sim import SimulationError
        self._SimulationError = SimulationError
        self._build_sim(self.nominal_params)
        self.ctrl = _import_controller()(params=self.nominal_params, dt=self.ctrl_dt,
                                         gravity_compensation=cfg["gravity_compensation"])

        rom = self.nominal_params.range_of_motion
        self.posture_map = PostureMap([rom.rud_min, rom.fe_min, rom.ps_min], [rom.rud_max, rom.fe_max, rom.ps_max])
        self.stiffness_map = StiffnessMap(self._lam_max(), self.nominal_params.spring.K, cfg["stiffness_map"])
        self.episode_steps = int(math.ceil(cfg["episode_s"] / self.ctrl_dt - 1e-9))

        mode = cfg["action_mode"]
        n_act = 6 if mode == "posture_compliance" else 4
        self.action_space = spaces.Box(-1.0, 1.0, shape=(n_act,), dtype=np.float32)
        if mode == "motor":
            self._motor_lo, self._motor_hi = self._motor_range()

        reward_names = COMMON_REWARD_TERMS + self.task_reward_terms
        unknown = sorted(set(cfg["reward"]) - set(reward_names))
        if unknown:
            raise EnvConfigError(f"unknown reward term(s) {', '.join('reward.' + u for u in unknown)} for task "
                                 f"'{self.task}'; allowed: {list(reward_names)}")
        self.reward_weights = {k: cfg["reward"][k] for k in reward_names if k in cfg["reward"]}

        self._terms = self._obs_terms()
        unknown = [n for n in cfg["observation"] if n not in self._terms]
        if unknown:
            raise EnvConfigError(f"unknown observation term(s) {unknown} for task '{self.task}'; "
                                 f"allowed: {list(self._terms)}")
        self.obs_terms = [self._terms[n] for n in cfg["observation"]]
        self.obs_slices: dict[str, slice] = {}
        i = 0
        for t in self.obs_terms:
            self.obs_slices[t.name] = slice(i, i + t.size)
            i += t.size
        self.obs_size = i
        self._obs_plan = [(self.obs_slices[t.name].start, self.obs_slices[t.name].stop, t.fn) for t in self.obs_terms]
        bound = lambda b, t: np.broadcast_to(np.asarray(b, dtype=np.float32), (t.size,))  # noqa: E731
        self._obs_low = np.concatenate([bound(t.low, t) for t in self.obs_terms]).astype(np.float32)
        self._obs_high = np.concatenate([bound(t.high, t) for t in self.obs_terms]).astype(np.float32)
        if cfg["obs_mode"] == "flat":
            self.observation_space = spaces.Box(self._obs_low, self._obs_high, dtype=np.float32)
        else:
            self.observation_space = spaces.Dict(
                {t.name: spaces.Box(self._obs_low[self.obs_slices[t.name]], self._obs_high[self.obs_slices[t.name]],
                                    dtype=np.float32) for t in self.obs_terms})

        self._renderer = None
        self._viewer = None
        cams = [self.model.camera(i).name for i in range(self.model.ncam)]
        if cfg["render"]["camera"] not in cams:
            raise EnvConfigError(f"'render.camera' = {cfg['render']['camera']!r} is not a camera of the model; "
                                 f"choose one of {cams}")
        self._reset_state()
        self._needs_reset = True  # step() before the first reset() is refused, as after an episode's end

    def _validate_task(self) -> None:
        """Cross-checks of the task section beyond per-field ranges (override in tasks)."""

    def _build_sim(self, params) -> None:
        self.params = params
        self.sim = self._WristSim(params=params, scene_fn=self._full_scene)
        self.model, self.data = self.sim.model, self.sim.data
        if self.cfg["physics_dt"] is not None:
            self.model.opt.timestep = self.cfg["physics_dt"]
            self.sim.timestep = self.cfg["physics_dt"]
        dt = float(self.model.opt.timestep)
        n = self.ctrl_dt / dt
        if abs(n - round(n)) > 1e-9 * n or round(n) < 1:
            raise EnvConfigError(f"'ctrl_dt' = {self.ctrl_dt:g} s must be a whole number of physics steps of "
                                 f"{dt:g} s (got {n:.6g}); choose ctrl_dt = k * physics_dt")
        self.n_substeps = int(round(n))
        self._settle_steps = max(1, int(round(self.cfg["settle_s"] / dt)))
        self._scene_ids()
        self._tool_body = self.model.body("tool").id
        self._nominal_tool_mass = float(self.model.body_mass[self._tool_body])
        self._nominal_tool_inertia = self.model.body_inertia[self._tool_body].copy()
        self._task_geoms = np.array([g for g in range(self.model.ngeom)
                                     if (self.model.geom(g).name or "").startswith("task_")], dtype=int)
        self._nominal_friction = self.model.geom_friction[self._task_geoms].copy()

    def _scene_ids(self) -> None:
        """Look up the task's model elements after (re)compilation (override in tasks)."""

    def _lam_max(self) -> float:
        """Smallest reachable upper bound of lam over a grid of the range of motion (N m)."""
        rom = self.nominal_params.range_of_motion
        his = [self.ctrl.lambda_range(np.array([a, b]))[1]
               for a in np.linspace(rom.rud_min, rom.rud_max, 5) for b in np.linspace(rom.fe_min, rom.fe_max, 5)]
        self._lam_hi_max = float(max(his))
        return float(min(his))

    def _motor_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Motor reference range for mode ``motor``: leg angles over the range of motion +- the deflection limit."""
        from ..kinematics import WristKinematics
        rom = self.nominal_params.range_of_motion
        kin = WristKinematics(self.nominal_params)
        q1 = np.array([kin.joint_angles(np.array([a, b]))[0::4]
                       for a in np.linspace(rom.rud_min, rom.rud_max, 7)
                       for b in np.linspace(rom.fe_min, rom.fe_max, 7)])
        dl = self.nominal_params.spring.deflection_limit
        lo = np.append(q1.min(axis=0) - dl, rom.ps_min)
        hi = np.append(q1.max(axis=0) + dl, rom.ps_max)
        return lo, hi

    # ------------------------------------------------------------------ observation terms
    def _obs_terms(self) -> dict[str, ObsTerm]:
        """Every observation term this task offers, with physical bounds (see ``ObsTerm``)."""
        n_act = self.action_space.shape[0]
        p = self.nominal_params
        dl, K2, d0 = p.spring.deflection_limit, 2.0 * p.spring.K, p.spring.delta0
        tau_bound = K2 * math.sinh(1.25 * dl / d0)
        lam_bound = 2.0 * self._lam_hi_max
        sig_bound = 10.0 * K2 / d0 * math.sqrt(1.0 + (tau_bound / K2) ** 2)
        half_pi, two_pi = 0.5 * math.pi, 2.0 * math.pi
        pl, ph = self.posture_map.lo, self.posture_map.hi
        terms = [
            ObsTerm("posture", 3, "rad", "measured RUD, FE, PS (with sensor noise)", self._obs_posture,
                    np.array([-half_pi, -half_pi, -two_pi]), np.array([half_pi, half_pi, two_pi])),
            ObsTerm("posture_rate", 3, "rad/s", "d/dt of the posture (with sensor noise)", self._obs_posture_rate,
                    -100.0, 100.0),
            ObsTerm("motor_angles", 4, "rad", "three PM motors and the PS motor", lambda: self.sim.motor_angles(),
                    -two_pi, two_pi),
            ObsTerm("deflections", 3, "rad", "spring deflections delta = q1 - theta", lambda: self._defl,
                    -math.pi, math.pi),
            ObsTerm("spring_torques", 3, "N m", "spring torques on the legs", self._obs_spring_torques,
                    -tau_bound, tau_bound),
            ObsTerm("stiffness", 3, "N m/rad", "coupler stiffness of the springs as they are, "
                    "J_a^T diag(sigma_s(delta)) J_a at the measured posture (RUD-RUD, RUD-FE, FE-FE; "
                    "paper's formula, no load term)",
                    self._obs_stiffness, -sig_bound, sig_bound),
            ObsTerm("lam", 1, "N m", "internal torque used (stiffness preload)", lambda: self.ctrl.lam,
                    -lam_bound, lam_bound),
            ObsTerm("prev_action", n_act, "-", "previous action", lambda: self._prev_action, -1.0, 1.0),
            ObsTerm("target", 3, "rad", "posture reference (RUD, FE, PS) now", lambda: self._target, pl, ph),
            ObsTerm("tool_wrench", 6, "N, N m", "hand-tool force/torque sensor, base frame (with noise)",
                    self._obs_wrench, np.array([-1e4] * 3 + [-1e3] * 3), np.array([1e4] * 3 + [1e3] * 3)),
            ObsTerm("contact_force", 1, "N", "normal force between the tool and the task's objects (Insertion: the "
                    "hole's walls and chamfers, not the fit plate) (with noise)",
                    self._obs_contact, 0.0, 1e5),
            ObsTerm("phase", 1, "-", "elapsed fraction of the episode",
                    lambda: self._step / self.episode_steps, 0.0, 1.0),
        ]
        out = {t.name: t for t in terms}
        for t in self._task_obs_terms():
            out[t.name] = t
        return out

    def _task_obs_terms(self) -> list[ObsTerm]:
        return []

    # sensor noise: one draw per observation, laid out as posture(3) posture_rate(3) force(3) torque(3) contact(1)
    _NOISE_LAYOUT = ("posture",) * 3 + ("posture_rate",) * 3 + ("force",) * 3 + ("torque",) * 3 + ("force",)

    def _draw_noise(self) -> None:
        self._nz = None if self._noise_std is None else self.np_random.normal(0.0, 1.0, 13) * self._noise_scale

    def _obs_posture(self):
        return self._posture if self._nz is None else self._posture + self._nz[0:3]

    def _obs_posture_rate(self):
        r = self.sim.posture_rate()
        return r if self._nz is None else r + self._nz[3:6]

    def _obs_wrench(self):
        w = self.sim.tool_wrench()
        return w if self._nz is None else w + self._nz[6:12]

    def _obs_contact(self):
        c = self._contact if self._nz is None else self._contact + self._nz[12]
        return c if c > 0.0 else 0.0  # a touch sensor never reads a pull

    def _obs_spring_torques(self):
        s = self.params.spring
        return -2.0 * s.K * np.sinh(self._defl / s.delta0)

    def _obs_stiffness(self):
        """The paper's J_a^T Sigma_s J_a from the measured deflections: the stiffness the springs give now
        (loads included), cheap (closed-form J_a, no Hessian); the ~13 % load term is left out."""
        # the posture is finite here (``step`` ends the episode otherwise), so skip kinematics_at's checks
        ay, az = self._posture_list[0], self._posture_list[1]
        _, Ja = self.ctrl._q1_ja(ay, az)
        s = self.params.spring
        c, d0 = 2.0 * s.K / s.delta0, s.delta0
        s00 = s01 = s11 = 0.0
        for (a, b), dk in zip(Ja, self._defl_list):
            sig = c * math.cosh(dk / d0)
            s00 += sig * a * a
            s01 += sig * a * b
            s11 += sig * b * b
        return (s00, s01, s11)

    def _raw_observation(self) -> np.ndarray:
        """All terms written into one new float64 array (so no term is ever a view of simulator memory)."""
        obs = np.empty(self.obs_size)
        for a, b, fn in self._obs_plan:
            obs[a:b] = fn()
        return obs

    def _observation(self):
        self._draw_noise()
        obs = self._raw_observation()
        # np.clip(obs, low, high) without its Python-level dispatch (same values, NaN passes through)
        np.maximum(obs, self._obs_low, out=obs)
        np.minimum(obs, self._obs_high, out=obs)
        obs = obs.astype(np.float32)
        if self.cfg["obs_mode"] == "dict":
            return {t.name: obs[self.obs_slices[t.name]].copy() for t in self.obs_terms}
        return obs

    # ------------------------------------------------------------------ actions
    def reference_to_action(self, posture_ref, stiffness: float) -> np.ndarray:
        """The ``posture_stiffness`` action (4,) that commands ``posture_ref`` (RUD, FE, PS; rad) with
        stiffness command ``stiffness`` in [-1, 1]: the inverse of that mode's mapping."""
        s = float(stiffness)
        if not (math.isfinite(s) and -1.0 <= s <= 1.0):
            raise ValueError(f"stiffness command must be in [-1, 1], got {stiffness!r}")
        ref = np.asarray(posture_ref, dtype=float)
        if ref.shape != (3,) or not np.isfinite(ref).all():
            raise ValueError(f"posture_ref must be 3 finite angles (RUD, FE, PS) in rad, got {posture_ref!r}")
        return np.append(self.posture_map.to_command(ref), s).astype(np.float32)

    def success_description(self) -> str:
        """The success criterion in words, with this instance's numbers."""
        return self.success_text.format(**{k: v for k, v in self.tp.items() if not isinstance(v, tuple)})

    def lam_to_stiffness_command(self, lam: float) -> float:
        """The stiffness command in [-1, 1] that maps to internal torque ``lam`` (N m), clipped to [0, lam_max]."""
        return self.stiffness_map.to_command(lam)

    def _motor_refs(self, a: np.ndarray) -> np.ndarray:
        mode = self.cfg["action_mode"]
        if mode == "motor":
            return self._motor_lo + 0.5 * (a + 1.0) * (self._motor_hi - self._motor_lo)
        if mode == "posture_stiffness":
            ref = self.posture_map.to_posture(a[:3])
            return self.ctrl.step(ref, lam=self.stiffness_map.to_lam(a[3]))
        if mode == "residual":
            r = self.cfg["residual"]
            ref = self.posture_map.clip(self._target + r["posture_scale"] * a[:3])
            s = r["stiffness_nominal"] + r["stiffness_scale"] * a[3]
            return self.ctrl.step(ref, lam=self.stiffness_map.to_lam(s))
        # posture_compliance: diagonal compliances log-mapped, off-diagonal as a correlation in (-0.9, 0.9)
        c = self.cfg["compliance"]
        ref = self.posture_map.to_posture(a[:3])
        lc = np.log(c["min"]) + 0.5 * (a[3:5] + 1.0) * (np.log(c["max"]) - np.log(c["min"]))
        d = np.exp(lc)
        off = 0.9 * a[5] * math.sqrt(d[0] * d[1])
        C = np.array([[d[0], off], [off, d[1]]])
        return self.ctrl.step(ref, compliance_ref=C)

    # ------------------------------------------------------------------ episode
    def _reset_state(self) -> None:
        self._step = 0
        self._t = 0.0
        self._prev_action = np.zeros(self.action_space.shape, dtype=np.float32)
        self._target = np.zeros(3)
        self._posture = np.zeros(3)
        self._defl = np.zeros(3)
        self._posture_list = [0.0, 0.0, 0.0]
        self._defl_list = [0.0, 0.0, 0.0]
        self._energy = 0.0
        self._contact = 0.0
        self._closure = 0.0
        self._peak_contact = 0.0
        self._sum_contact_sq = 0.0
        self._noise_std = None
        self._nz = None
        self._latency = 0.0
        self._theta_prev = None
        self._history: dict[str, list] = {"error": [], "energy": [], "contact": []}

    def _randomize(self) -> None:
        rnd = self.cfg["randomize"]
        rng = self.np_random

        def factor(term):
            spec = rnd[term]
            return float(rng.uniform(*spec["range"])) if spec["enabled"] else 1.0

        if any(rnd[t]["enabled"] for t in DEVICE_TERMS):
            p = self.nominal_params
            f = {t: factor(t) for t in DEVICE_TERMS}
            params = p.replace(
                spring={"K": p.spring.K * f["spring_K"], "delta0": p.spring.delta0 * f["spring_delta0"]},
                motor={"time_constant": p.motor.time_constant * f["motor_time_constant"]},
                inertia={"link_mass": [m * f["link_mass"] for m in p.inertia.link_mass],
                         "link_inertia": [i * f["link_mass"] for i in p.inertia.link_inertia],
                         "hand_mass": p.inertia.hand_mass * f["hand_mass"]},
                damping={"leg_joint": p.damping.leg_joint * f["damping"],
                         "ps_joint": p.damping.ps_joint * f["damping"]})
            self._close_renderer()
            self._build_sim(params)
        ft = factor("tool_mass")
        self.model.body_mass[self._tool_body] = self._nominal_tool_mass * ft
        self.model.body_inertia[self._tool_body] = self._nominal_tool_inertia * ft
        ff = factor("friction")
        if self._task_geoms.size:
            self.model.geom_friction[self._task_geoms] = self._nominal_friction * ff
        lat = rnd["latency"]
        # latency in whole physics steps, at most one step short of the control period
        dt = float(self.model.opt.timestep)
        steps = int(round(float(rng.uniform(*lat["range"])) / dt)) if lat["enabled"] else 0
        self._latency = min(steps, self.n_substeps - 1) * dt
        noise = rnd["sensor_noise"]
        self._noise_std = {k: float(noise[k]) for k in ("posture", "posture_rate", "force", "torque")} \
            if noise["enabled"] else None
        if self._noise_std is not None:
            self._noise_scale = np.array([self._noise_std[k] for k in self._NOISE_LAYOUT])

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._reset_state()
        self._randomize()
        u0, ps0, s0 = self._task_reset(self.np_random)
        lam0 = self.stiffness_map.to_lam(s0)
        self.sim.reset(u=tuple(u0), ps=float(ps0), lam=lam0)
        self.ctrl.reset(posture=(float(u0[0]), float(u0[1]), float(ps0)), lam=lam0)
        self.sim.apply_wrench(np.zeros(3), np.zeros(3))
        if self.cfg["settle_s"] > 0.0:
            # let the wrist settle under gravity at the initial references (the simulator starts at rest at
            # the exact posture, which is not an equilibrium once the hand's and the tool's weight act)
            self.sim.set_motor_references(self.ctrl.step(np.array([u0[0], u0[1], ps0]), lam=lam0))
            self.sim.step(self._settle_steps * self.model.opt.timestep)
        self._after_reset()
        self._target = self._reference(0.0)
        self._measure()
        self._closure = self.sim.loop_closure_peak() if self.cfg["settle_s"] > 0.0 else \
            self.sim.loop_closure_error()
        self._needs_reset = False
        self._theta_prev = None
        if self.cfg["action_mode"] == "residual":
            self._prev_action = np.zeros(self.action_space.shape, dtype=np.float32)
        return self._observation(), self._info({}, final=False)

    def step(self, action):
        if self._needs_reset:
            raise ResetNeeded("step() called after the episode ended (terminated or truncated) or before the "
                              "first reset(); call reset() to start an episode")
        a = check_action(action, self.action_space.shape)
        a = np.maximum(a, -1.0)  # = np.clip(a, -1, 1) (a is finite), a new array: the caller's is untouched
        np.minimum(a, 1.0, out=a)
        theta = self._motor_refs(a)
        self._before_physics(self._t)
        failure = None
        try:
            if self._latency > 0.0 and self._theta_prev is not None:
                self._advance(self._latency, True)
                self.sim.set_motor_references(theta)
                self._advance(self.ctrl_dt - self._latency, False)
            else:
                self.sim.set_motor_references(theta)
                self._advance(self.ctrl_dt, True)
        except self._SimulationError as exc:
            failure = str(exc)
        self._theta_prev = theta
        self._step += 1
        self._t = self._step * self.ctrl_dt
        self._measure()
        if failure is None and not all(x - x == 0.0 for x in self._posture_list + self._defl_list):  # finite?
            failure = f"non-finite state at t = {self._t:.3f} s"
        # the physics' validity: measured before a failure resets the simulator (MuJoCo has then already reset
        # its state, so the opening is unknown: inf)
        self._closure = self.sim.loop_closure_peak() if failure is None else math.inf
        if failure is not None:
            # the physics diverged (MuJoCo resets its state when it does): end the episode with the
            # termination penalty, from a clean, finite state so that the last observation is valid
            self.sim.reset()
            self.sim.apply_wrench(np.zeros(3), np.zeros(3))
            self._measure()
        self._target = self._reference(self._t)
        self._peak_contact = max(self._peak_contact, self._contact)
        self._sum_contact_sq += self._contact * self._contact

        err = wrap_angle(self._posture - self._target)
        energy = self._energy
        self._history["error"].append(err)
        self._history["energy"].append(energy)
        self._history["contact"].append(self._contact)
        sc = self.cfg["scales"]
        raw = {
            "tracking": -math.sqrt(_sum_sq(self._tracking_error(err))) / sc["tracking"],
            "energy": -energy / sc["energy"],
            "action_rate": -_sum_sq(a - self._prev_action) / a.size,
            "termination": -1.0 if failure is not None else 0.0,
        }
        raw.update(self._task_reward_terms(err))
        weighted = {f"reward_{k}": w * raw[k] for k, w in self.reward_weights.items()}
        reward = 0.0
        for v in weighted.values():
            reward += v
        self._prev_action = a.astype(np.float32)
        terminated = failure is not None
        time_up = not terminated and self._step >= self.episode_steps
        # closure_truncate: the welds opened past closure_warn, so the physics from here on is not trustworthy
        cut = not terminated and self._closure_truncate and self._closure > self._closure_warn
        truncated = time_up or cut
        self._needs_reset = terminated or truncated
        obs = self._observation()
        info = self._info(weighted, final=time_up and not cut, err=err)
        info["posture_error_vec"] = err
        if terminated:
            info["simulation_error"] = failure
        return obs, float(reward), terminated, truncated, info

    def _measure(self) -> None:
        """Read the simulator once per step (``posture()`` also brings its sensors up to date, unless
        neither the task nor the observation reads them: then only poses and velocities are updated)."""
        if not (self.reads_sensors or "tool_wrench" in self.cfg["observation"]):
            self.sim.sync_kinematics()
        self._posture = self.sim.posture()
        self._defl = self.sim.deflections()
        self._posture_list = self._posture.tolist()
        self._defl_list = self._defl.tolist()
        s = self.params.spring
        c0, c1, c2 = (np.cosh(self._defl / s.delta0) - 1.0).tolist()
        self._energy = float(2.0 * s.K * s.delta0 * (c0 + c1 + c2))  # = np.sum of 3 terms, same order
        self._contact = self._contact_force()

    def _info(self, weighted: dict, final: bool, err: np.ndarray | None = None) -> dict:
        if err is None:
            err = wrap_angle(self._posture - self._target)
        n = max(self._step, 1)
        info = dict(weighted)
        info.update(
            posture_error=math.sqrt(float(err @ err)),
            contact_force=float(self._contact),
            peak_contact_force=float(self._peak_contact),
            rms_contact_force=float(math.sqrt(self._sum_contact_sq / n)),
            elastic_energy=self._energy,
            lam=float(self.ctrl.lam),
            loop_closure=self._closure,
            closure_exceeded=self._closure > self._closure_warn,
            time=self._t,
            is_success=bool(self._success()) if final else False,
        )
        return info

    def elastic_energy(self) -> float:
        """Energy stored in the three springs (J): sum of 2 K delta0 (cosh(delta/delta0) - 1), the integral of
        the spring law, with the simulator's (possibly randomised) spring parameters."""
        s = self.params.spring
        d = np.asarray(self.sim.deflections(), dtype=float)
        return float(2.0 * s.K * s.delta0 * np.sum(np.cosh(d / s.delta0) - 1.0))

    # ------------------------------------------------------------------ task hooks
    def _full_scene(self, spec: mujoco.MjSpec) -> None:
        """The task's geometry plus a camera ``task_view`` that frames the hand, the tool and the task objects."""
        self._scene(spec)
        pos, target = np.array([0.42, -0.32, 0.16]), np.array([0.17, 0.0, -0.03])
        f = (target - pos) / np.linalg.norm(target - pos)
        x = np.cross(f, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(x, f)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.column_stack([x, y, -f]).ravel())  # a camera looks along its -Z
        spec.worldbody.add_camera(name="task_view", pos=list(pos), quat=list(q), fovy=45.0)

    def _scene(self, spec: mujoco.MjSpec) -> None:
        """Add task geometry to the model before compilation."""

    def _task_reset(self, rng: np.random.Generator) -> tuple[np.ndarray, float, float]:
        """Sample the episode; return the initial posture u (2,), PS angle and stiffness command."""
        raise NotImplementedError

    def _after_reset(self) -> None:
        """Place task objects once the simulator is at its initial state."""

    def _reference(self, t: float) -> np.ndarray:
        raise NotImplementedError

    def _before_physics(self, t: float) -> None:
        """Apply external loads for the coming control period."""

    def _advance(self, duration: float, first: bool) -> None:
        """Advance the physics by ``duration`` within a control period (``first``: its first part, where the
        loop-closure peak restarts). Tasks that must see every substep (a force averaged over the period, the
        instant of an impact) override it and step one substep at a time."""
        if first:
            self.sim.step(duration)
        else:
            self.sim.step(duration, restart_peak=False)

    def _contact_force(self) -> float:
        """Contact force (N) after a step; the simulator's sensors are current (``posture()`` synced them)."""
        return 0.0

    def _tracking_error(self, err: np.ndarray) -> np.ndarray:
        """The part of the posture error (RUD, FE, PS) that the tracking reward counts."""
        return err

    def _task_reward_terms(self, err: np.ndarray) -> dict[str, float]:
        return {}

    def _success(self) -> bool:
        raise NotImplementedError

    # ------------------------------------------------------------------ helpers for tasks
    def _window(self, seconds: float) -> int:
        return max(1, int(round(seconds / self.ctrl_dt)))

    def _add_touch_sensor(self, spec: mujoco.MjSpec, body, name: str, size, pos=(0.0, 0.0, 0.0), quat=None) -> None:
        kw = {"quat": quat} if quat is not None else {}
        body.add_site(name=f"{name}_site", type=mujoco.mjtGeom.mjGEOM_BOX, size=list(size), pos=list(pos),
                      rgba=[0, 0, 0, 0], group=5, **kw)
        spec.add_sensor(name=name, type=mujoco.mjtSensor.mjSENS_TOUCH, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname=f"{name}_site")

    def tool_point(self, u, ps: float, p_tool) -> np.ndarray:
        """World position (m) of point ``p_tool`` (tool frame) at posture u (2,), PS angle ps, from the analytic
        kinematics: O_c + R_c Rx(ps) (hand_offset e_x + p_tool). Used to place task objects."""
        from ..kinematics import WristKinematics, rot_x
        if not hasattr(self, "_kin"):
            self._kin = WristKinematics(self.nominal_params)
        T = self._kin.coupler_pose(np.asarray(u, dtype=float), allow_outside=True)
        p = np.array([self.nominal_params.inertia.hand_offset, 0.0, 0.0]) + rot_x(ps) @ np.asarray(p_tool, float)
        return T[:3, 3] + T[:3, :3] @ p

    def _add_tool_geom(self, spec: mujoco.MjSpec, name: str, fromto, radius: float, mass: float,
                       friction: float = 0.5) -> None:
        """A capsule on the ``tool`` body that collides with task objects only (contype 2 / conaffinity 0)."""
        spec.body("tool").add_geom(name=f"task_{name}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, fromto=list(fromto),
                                   size=[radius, 0, 0], mass=mass, contype=2, conaffinity=0,
                                   friction=[friction, 0.005, 0.0001], rgba=[0.55, 0.55, 0.6, 1], group=1,
                                   condim=3, solref=list(CONTACT_SOLREF))

    def _sensor_adr(self, name: str) -> int:
        return int(self.model.sensor_adr[self.model.sensor(name).id])

    # ------------------------------------------------------------------ rendering
    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        if self.render_mode == "rgb_array":
            if self._renderer is None:
                self._renderer = mujoco.Renderer(self.model, self.cfg["render"]["height"], self.cfg["render"]["width"])
            self.sim.sync()  # brings body poses (and cameras) up to date after a step
            self._renderer.update_scene(self.data, camera=self.cfg["render"]["camera"])
            return self._renderer.render().copy()
        if self._viewer is None:
            import os
            import sys
            has_display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
            if sys.platform.startswith("linux") and not has_display:
                # MuJoCo's GLFW viewer aborts the whole process without a display; fail cleanly instead
                raise RuntimeError("render_mode='human' needs a display (DISPLAY or WAYLAND_DISPLAY is not set); "
                                   "use render_mode='rgb_array' with MUJOCO_GL=egl on a headless machine")
            from mujoco import viewer as mj_viewer  # needs a display (GLFW)
            self._viewer = mj_viewer.launch_passive(self.model, self.data)
        self._viewer.sync()
        return None

    def _close_renderer(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    def close(self):
        self._close_renderer()

    # ------------------------------------------------------------------ pickling
    def __getstate__(self):
        """Pickle the settings and the full episode state; MuJoCo objects are rebuilt on load."""
        state = {k: v for k, v in self.__dict__.items()
                 if k not in ("sim", "model", "data", "_renderer", "_viewer", "_WristSim", "_terms", "obs_terms",
                              "_SimulationError",
                              "_obs_plan")}
        state["_sim_state"] = self.sim.get_state()
        state["_model_mutable"] = (self.model.body_mass.copy(), self.model.body_inertia.copy(),
                                   self.model.geom_friction.copy(), self.model.dof_frictionloss.copy())
        return state

    def __setstate__(self, state):
        sim_state = state.pop("_sim_state")
        mass, inertia, friction, frictionloss = state.pop("_model_mutable")
        self.__dict__.update(state)
        self._WristSim = _import_sim()
        from ..sim import SimulationError
        self._SimulationError = SimulationError
        self._renderer = None
        self._viewer = None
        self.sim = self._WristSim(params=self.params, scene_fn=self._full_scene)
        self.model, self.data = self.sim.model, self.sim.data
        if self.cfg["physics_dt"] is not None:
            self.model.opt.timestep = self.cfg["physics_dt"]
            self.sim.timestep = self.cfg["physics_dt"]
        self._scene_ids()
        self.model.body_mass[:] = mass
        self.model.body_inertia[:] = inertia
        self.model.geom_friction[:] = friction
        self.model.dof_frictionloss[:] = frictionloss
        self.sim.set_state(sim_state)
        self._terms = self._obs_terms()
        self.obs_terms = [self._terms[n] for n in self.cfg["observation"]]
        self._obs_plan = [(self.obs_slices[t.name].start, self.obs_slices[t.name].stop, t.fn) for t in self.obs_terms]
