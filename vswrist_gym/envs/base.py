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

This module holds the construction and the step; the rest of ``VSWristEnv`` comes from one module per job: the task
hooks' defaults (``hooks``), the reset sequence (``reset``), the episode state as arrays shared with a batch
(``episode``), how a step ends (``ending``: divergence and the episode's end, over arrays of worlds, shared with the
batch), rendering (``render``), pickling (``pickling``), and the actions, observations, rewards, randomisation and
scene helpers (``actions``, ``observations``, ``rewards``, ``randomization``, ``shared``).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.error import ResetNeeded

from ..params import load_params
from ..stiffness import stored_energy
from .actions import ActionsMixin, PostureMap, StiffnessMap, check_action, clip_action
from .config import EnvConfigError, load_env_config, merge, validate_task
from .ending import episode_end, restart_failed, step_failures
from .episode import EpisodeState, EpisodeStateMixin, held_substeps, record_contact, record_history, tick
from .hooks import TaskHooks
from .observations import ObservationsMixin
from .pickling import PicklingMixin
from .randomization import RandomizationMixin
from .render import RenderMixin
from .reset import ResetMixin
from .rewards import COMMON_REWARD_TERMS, RewardsMixin, wrap_angle
from .shared import SceneMixin


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


class VSWristEnv(TaskHooks, ResetMixin, RenderMixin, PicklingMixin, EpisodeStateMixin, ActionsMixin, ObservationsMixin,
                 RandomizationMixin, RewardsMixin, SceneMixin, gym.Env):
    """Base class of every VS-Wrist task (do not instantiate directly; use ``gymnasium.make``).

    How to write a task (``load_hold.py`` is the shortest example): a module ``envs/<task>.py`` with a subclass
    and a config ``configs/envs/<task>.yaml`` (its ``task:`` section), registered in ``vswrist_gym.ENV_IDS``
    (which also gives it ``gym.make_vec``). The subclass sets

    * ``task`` (the config file stem), ``task_id``, ``summary``, ``success_text`` (formatted with the task
      settings), ``task_spec`` (name -> ("number" | "interval" | "int_interval", lo, hi) or ("choice", names,
      None): validation of the ``task`` section, read as ``self.tp``), ``task_reward_terms`` (names of its extra
      reward terms), ``reads_sensors`` (False if it reads only poses: a cheaper update after each step);

    and ``task_state`` (``hooks.TaskHooks``): its own episode state, {name: (the shape of one world's value,
    dtype)}, which every world keeps in its row of ``EpisodeState.task`` (a batch's (N, ...) arrays; each world's
    read as an attribute through ``episode.task_field``); and implements the hooks. The per-step hooks and the
    success are written over arrays of worlds, as class methods ``<hook>_worlds(worlds, ep, ids, ...)`` that read
    (and write) the rows ``ids`` of the episode state ``ep``: a batch calls them once for its live worlds, the
    single env with itself as a batch of one (``hooks`` has the contract; LoadHold and Impact are the examples).
    A task not yet written so implements the one-world form instead (``_contact_force()``, ...: ``self`` is the
    world, which keeps its episode state on ``self`` and draws only from the ``rng`` it is given), which a batch
    calls world by world:

    * ``_scene(spec)``: add geometry to the MjSpec before compilation (``SceneMixin`` helpers in ``shared``:
      ``_add_tool_geom``, ``_add_touch_sensor``, ``add_mocap_box_body``); ``_scene_ids()``: look up ids after;
    * ``_task_reset(rng) -> (u (2,), ps, stiffness command)``: sample the episode into this world's row of the
      task state (``self._ep.task``); optionally the class method ``_reset_worlds(worlds)``: what the episode's
      set-up computes over the worlds that reset together (Hammer's swing); ``_after_reset()``: place objects once
      the wrist stands at its initial posture (``tool_point``);
    * ``_reference(t) -> (..., 3)``: the posture reference (RUD, FE, PS) at time t (s), a number or an array of
      times (written over arrays: each reset evaluates the episode's control instants in one call);
    * ``_before_physics_worlds(worlds, ep, ids)``: external loads for the coming period
      (``WristSim.apply_wrenches``), or ``_before_physics(t)`` (``self.sim.apply_wrench``);
    * ``_contact_force_worlds(worlds, ep, ids) -> (L,)`` (N, after a step), ``_tracking_error(err)`` (the part of
      the error the tracking reward counts, indexing the last axis only: ``err[..., 1:]``; it gets (3,) or
      (N, 3)), ``_task_reward_terms_worlds(worlds, ep, ids, err) -> {name: (L,) unweighted values}``,
      ``_task_info_worlds(worlds, ep, ids) -> {name: (L,)}`` (extra ``info`` entries, the same keys every step),
      ``_success_worlds(worlds, ep, ids) -> (L,) bool`` (at the episode's last step, from its history:
      ``episode.episode_history``), optionally ``_task_obs_terms()`` (``ObsTerm``s: over arrays of worlds,
      ``of(measures)``, as LoadHold's and Drill's cues, which read the task state with ``measures.state(name)``,
      and Polish's target force, a table's entry at the step with ``measures.state_at_step(name)``; or one world's
      ``fn()``, which a batch calls world by world) and ``_validate_task()``.

    Everything else (actions, observations, noise, randomisation, rewards, info, divergence, rendering,
    pickling, batching) comes from the base and its mixins and needs no task code.
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
    def __init__(self, render_mode: str | None = None, config: Mapping[str, Any] | None = None, *,
                 id_config: Mapping[str, Any] | None = None, **overrides: Any):
        """``config`` and ``overrides``: settings over the task's config files. ``id_config``: what the registered
        id fixes (``vswrist_gym.ENV_KWARGS``: an older version of a task), applied under the caller's settings."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, "
                             f"got {render_mode!r}")
        if config is not None and not isinstance(config, Mapping):
            raise EnvConfigError(f"'config' must be a mapping of settings (e.g. {{'reward': {{'energy': 0.5}}}}), "
                                 f"got {type(config).__name__} {config!r}")
        if id_config is not None and not isinstance(id_config, Mapping):
            raise EnvConfigError(f"'id_config' must be a mapping of settings, got {type(id_config).__name__} "
                                 f"{id_config!r}")
        user = dict(config or {})
        user.update(overrides)
        self._user_config = user
        cfg = load_env_config(self.task, merge(id_config, user) if id_config else user)
        self.cfg = cfg
        self.tp = validate_task(cfg["task"], self.task_spec, self.task)
        self.render_mode = render_mode
        self.nominal_params = load_params(cfg["params"])
        self._validate_task()
        self.params = self.nominal_params
        self.ctrl_dt = cfg["ctrl_dt"]
        self._closure_warn, self._closure_truncate = cfg["closure_warn"], cfg["closure_truncate"]
        # neither the task nor the observation reads sensors: a step updates only poses and velocities
        self._light_sync = not (self.reads_sensors or "tool_wrench" in cfg["observation"])
        self.metadata = dict(self.metadata, render_fps=int(round(1.0 / self.ctrl_dt)))
        self.episode_steps = int(math.ceil(cfg["episode_s"] / self.ctrl_dt - 1e-9))
        mode = cfg["action_mode"]
        n_act = 6 if mode == "posture_compliance" else 4
        # the episode state (``episode``), before the simulator whose springs it holds; a batch makes it a row of its
        # own (``episode.share``). It starts ended: step() before the first reset() is refused, as after an
        # episode's end
        self._ep = EpisodeState(1, self.episode_steps, n_act, self.task_state)

        self._import_simulator()
        self._build_sim(self.nominal_params)
        self.ctrl = _import_controller()(params=self.nominal_params, dt=self.ctrl_dt,
                                         gravity_compensation=cfg["gravity_compensation"],
                                         payload=self._compensated_payload() if cfg["compensate_tool"] else ())
        self._use_episode_state(self._ep)

        rom = self.nominal_params.range_of_motion
        self.posture_map = PostureMap([rom.rud_min, rom.fe_min, rom.ps_min], [rom.rud_max, rom.fe_max, rom.ps_max])
        self.stiffness_map = StiffnessMap(self._lam_max(), self.nominal_params.spring.K, cfg["stiffness_map"])

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
        bound = lambda b, t: np.broadcast_to(np.asarray(b, dtype=np.float32), (t.size,))  # noqa: E731
        self._obs_low = np.concatenate([bound(t.low, t) for t in self.obs_terms]).astype(np.float32)
        self._obs_high = np.concatenate([bound(t.high, t) for t in self.obs_terms]).astype(np.float32)
        # what the float64 raw observation is clipped to: the float32 bounds' values, cast once, not at every step
        self._obs_bounds = (self._obs_low.astype(np.float64), self._obs_high.astype(np.float64))
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

    def _import_simulator(self) -> None:
        """The simulator's classes, on this world (construction and unpickling)."""
        self._WristSim = _import_sim()
        from ..sim import SimulationError
        self._SimulationError = SimulationError

    def _make_sim(self, params) -> None:
        """This task's simulator with ``params``, at the config's ``physics_dt`` (construction, a randomised
        model's rebuild, unpickling)."""
        self.sim = self._WristSim(params=params, scene_fn=self._full_scene)
        self.model, self.data = self.sim.model, self.sim.data
        if self.cfg["physics_dt"] is not None:
            self.model.opt.timestep = self.cfg["physics_dt"]
            self.sim.timestep = self.cfg["physics_dt"]

    def _build_sim(self, params) -> None:
        """The simulator with ``params`` and what the step reads of its model (substeps, ids, nominal values)."""
        self.params = params
        self._ep.put(0, spring_K=params.spring.K, spring_delta0=params.spring.delta0)
        self._make_sim(params)
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

    def success_description(self) -> str:
        """The success criterion in words, with this instance's numbers."""
        return self.success_text.format(**{k: v for k, v in self.tp.items() if not isinstance(v, tuple)})

    # ------------------------------------------------------------------ step
    def step(self, action):
        if self._needs_reset:
            raise ResetNeeded("step() called after the episode ended (terminated or truncated) or before the "
                              "first reset(); call reset() to start an episode")
        a = check_action(action, self.action_space.shape)
        self._begin_step(a)
        self._advance()
        return self._finish_step()

    # One step in three phases, so that a batch (``batch.VSWristVectorEnv``) runs the physics of all its worlds
    # together (on threads) between the Python phases: ``_begin_step`` (action -> motor references, task loads),
    # ``_advance`` (the physics only: touches nothing but this world's MjModel/MjData, so worlds may advance
    # concurrently) and ``_finish_step`` (measures, reward, observation, info).
    def _begin_step(self, a: np.ndarray) -> None:
        """``a``: a checked action (``check_action``); clipped here to [-1, 1]."""
        a = clip_action(a)
        ep = self._ep
        ep.action[0] = a
        ep.theta[0] = self._motor_refs(a)  # the controller writes its command into the episode state
        self._before_physics(self._t)

    def _advance(self) -> None:
        ep = self._ep
        theta = ep.theta[0]
        ep.diverged[0] = False
        try:
            if held_substeps(ep.latency.item(0), ep.step.item(0)):
                latency = self._latency
                self._advance_physics(latency, True)
                self.sim.set_motor_references(theta)
                self._advance_physics(self.ctrl_dt - latency, False)
            else:
                self.sim.set_motor_references(theta)
                self._advance_physics(self.ctrl_dt, True)
        except self._SimulationError as exc:
            ep.diverged[0] = True
            self._sim_error = str(exc)
            return
        # bring what ``_measure`` reads up to date here, so that in a batch this C work runs on the threads too
        # (the same calls ``_measure`` would make; they find nothing stale afterwards)
        if self._light_sync:
            self.sim.sync_kinematics()
        else:
            self.sim.sync()

    def _advance_physics(self, duration: float, first: bool) -> None:
        """Advance the physics by ``duration`` within a control period (``first``: its first part, where the
        loop-closure peak restarts). Runs on a batch's threads: the physics only, one ``mj_step`` call. Tasks that
        must see every substep (a force averaged over the period, the instant of an impact) measure inside it
        with a plugin (``shared.PeriodMeanForce``) rather than stepping one substep at a time."""
        if first:
            self.sim.step(duration)
        else:
            self.sim.step(duration, restart_peak=False)

    def _finish_step(self):
        ep = self._ep
        a = ep.action[0]
        k, t = self._tick()
        self._measure()
        failures = step_failures({0: self._sim_error} if ep.diverged.item(0) else {}, ep.posture, ep.defl, [t])
        # the physics' validity, read only where the physics did not fail (MuJoCo reset a diverged state, so its
        # opening is not there to read: ``restart_failed`` makes it inf)
        closure = [math.inf if failures else self.sim.loop_closure_peak()]
        restart_failed([self], failures, closure)
        ep.closure[0] = closure[0]
        failure = failures.get(0)
        target = ep.target[0] = ep.references[0, k]
        err = wrap_angle(ep.posture[0] - target)
        self._record_step(err)
        weighted, reward = self._step_reward(err, ep.energy.item(0), a, ep.prev_action[0], failure is not None,
                                             self._task_reward_terms(err))
        weighted = {name: float(v) for name, v in weighted.items()}
        ep.prev_action[0] = a  # rounded to float32, as the observation has it
        terminated = failure is not None
        time_up, cut, truncated = episode_end(terminated, k, self.episode_steps, closure[0],
                                              self._closure_warn, self._closure_truncate)
        truncated = bool(truncated)
        ep.ended[0] = terminated or truncated
        obs = self._observation()
        info = self._info(weighted, final=bool(time_up & ~cut), err=err)
        info["posture_error_vec"] = err
        if terminated:
            info["simulation_error"] = failure
        return obs, float(reward), terminated, truncated, info

    def _tick(self) -> tuple[int, float]:
        """The step's clock after the physics (``episode.tick``, as a batch's over its worlds): the step count and
        time advance; returns them."""
        ep = self._ep
        k, t = tick(ep.step.item(0), self.ctrl_dt)
        ep.step[0] = k
        ep.t[0] = t
        return k, t

    def _record_step(self, err: np.ndarray) -> None:
        """The episode's record after a step's measures: the contact force's peak and sum of squares
        (``episode.record_contact``, as a batch's over its worlds), and the history."""
        ep = self._ep
        peak, sum_sq = record_contact(ep.peak_contact.item(0), ep.sum_contact_sq.item(0), ep.contact.item(0))
        ep.peak_contact[0] = peak
        ep.sum_contact_sq[0] = sum_sq
        record_history(ep, 0, ep.step.item(0), err)

    def _measure(self) -> None:
        """Read the simulator once per step (``posture()`` also brings its sensors up to date, unless
        neither the task nor the observation reads them: then only poses and velocities are updated)."""
        if self._light_sync:
            self.sim.sync_kinematics()
        ep = self._ep
        ep.posture[0] = self.sim.posture()
        D = self.sim.deflections()
        ep.defl[0] = D
        ep.energy[0] = float(stored_energy(D, self.params))
        ep.contact[0] = self._contact_force()
