"""The array step: ``VSWristEnv._begin_step`` and ``_finish_step`` of a batch's live worlds, over arrays
(``VSWristVectorEnv``'s mixin), for every batch, one world or many.

Before the physics: action clipping and maps, the ``motor`` mode's map and the analytic controller (modes
``posture_stiffness`` and ``residual``: ``AnalyticController.step_batch``) over arrays of worlds, the compliance
mode's LM dynamics world by world, into the episode state's actions, motor references and the controllers'
commands (``episode``: each world's controller keeps its command in its row); then the task's loads,
``_before_physics_worlds``.

After the physics: every world's simulator is read (posture, deflections, rates, loop closure, the tool wrench: what
``batch_sim.gather_plan`` names, copied into one (N, .) array by the compiled advance on the physics threads, or in
Python without it, and computed over arrays by ``BatchSim``'s reads), its reference (a row of the table its reset
computed: ``_reference`` is written over arrays of times) and its sensor noise (a row of the table its reset drew);
the task's hooks run once for all the live worlds, in their form over arrays (``hooks``: the single env runs the same
code on its one world; a task's hook or observation term written for one world is asked world by world); the
observation, the reward terms and the info metrics are the single env's own functions over arrays
(``observations.observe``, ``rewards.common_reward_terms``, ``weigh``, ``step_metrics``), and the rest is the single
env's operations in its order, so world i of a batch is the single env with seed s + i (to the bit on one machine:
``tests/test_batch.py`` checks 1e-9). A task may change the step through its hooks, not by overriding one of the
``STEP_METHODS`` (such a task is refused when its batch is made).
"""

from __future__ import annotations

import numpy as np

from ..stiffness import SpringLaw, stored_energy
from .actions import clip_action
from .ending import episode_end, restart_failed, step_failures
from .episode import record_contact, record_history, tick
from .observations import observe
from .rewards import step_metrics, wrap_angle
from .shared import sensor_values

# the single env's step methods that the array step computes over arrays (a batch of a task overriding one is
# refused: the batch would not run the override); the hooks it calls per world, or over arrays
# (``_tracking_error``), stay the task's, and what the single env and the batch both run (the reward,
# ``_step_reward``; the observation terms, ``_obs_terms``) takes a task's override in both
STEP_METHODS = ("_begin_step", "_finish_step", "_motor_refs", "_measure", "_info", "_observation", "_draw_noise")


class BatchMeasures:
    """``observations.observe``'s measures of a batch's live worlds after a step: (N, ...) arrays, and the reads
    of their simulators over arrays from the gathered rows ``G`` (``BatchSim``'s reads)."""

    __slots__ = ("worlds", "task", "ids", "bsim", "G", "posture", "deflections", "Q", "law", "contact", "lam",
                 "prev_action", "target", "step", "time", "noise")

    def __init__(self, worlds, task, ids, bsim, G, P, D, Q, law, contact, lam, prev_action, target, step, time,
                 noise):
        self.worlds, self.task, self.ids, self.bsim, self.G, self.Q = worlds, task, ids, bsim, G, Q
        self.posture, self.deflections, self.law, self.contact = P, D, law, contact
        self.lam, self.prev_action, self.target, self.step = lam, prev_action, target, step
        self.time, self.noise = time, noise

    def state(self, name: str) -> np.ndarray:
        """A field of the task's state (``TaskState``) of every world (N, ...)."""
        return getattr(self.task, name)[self.ids]

    def state_at_step(self, name: str) -> np.ndarray:
        """A field of the task's state that is a table over the episode's control instants (N, steps + 1, ...), each
        world's entry at its step."""
        return getattr(self.task, name)[self.ids, self.step]

    def posture_rate(self) -> np.ndarray:
        return self.bsim.read_posture_rate(self.G, self.posture)

    def motor_angles(self) -> np.ndarray:
        return self.bsim.read_motor_angles(self.Q)

    def tool_wrench(self) -> np.ndarray:
        return self.bsim.read_tool_wrench(self.G)

    def jacobian(self) -> np.ndarray:
        # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
        P = self.posture
        _, (J0, J1), _, _ = self.worlds[0].ctrl.posture_kinematics_batch(P[:, 0], P[:, 1], with_q1=False)
        return np.stack([J0.T, J1.T], axis=-1)

    def sensor(self, adr: int) -> np.ndarray:
        return sensor_values(self.worlds, adr)

    def task_term(self, term) -> np.ndarray:
        """A task's own term, world by world (it reads each world's state)."""
        name, L = term.name, len(self.worlds)
        return np.array([e._terms[name].fn() for e in self.worlds], dtype=float).reshape(L, term.size)


class ArrayStepMixin:
    """``_begin`` and ``_finish`` of ``VSWristVectorEnv``: the single env's step phases over arrays of worlds."""

    def _begin(self, worlds: list, ids: np.ndarray, acts: np.ndarray) -> np.ndarray:
        """Action -> controller -> motor references of the live worlds (``VSWristEnv._begin_step``; ``ids``: their
        indices in the batch), over arrays except the compliance mode's LM dynamics, world by world: the clipped
        actions, the motor references (L, 4) and the controllers' commands go into the episode state; returns the
        references."""
        A = clip_action(acts)
        first = worlds[0]
        mode = self._mode
        ep = self._ep
        if mode in ("posture_stiffness", "residual"):
            target = ep.target[ids] if mode == "residual" else None
            ref, lam = first._posture_command(A, target)
            # every world's controller has the nominal parameters (randomisation rebuilds the simulator only)
            theta, lam, command = first.ctrl.step_batch(ref, lam)
            ep.put(ids, command=command, lam=lam)  # the worlds' controllers' state: each reads its row
        elif mode == "motor":  # no controller: every world's map is the same (the nominal range of motion), and
            # its command stays the reset's
            theta = first._motor_refs(A)
        else:  # posture_compliance: the LM dynamics of each world's controller, which writes its row's command
            theta = np.array([e._motor_refs(a) for e, a in zip(worlds, A)])
        ep.put(ids, action=A, theta=theta)
        if self._hook_before:
            type(first)._before_physics_worlds(worlds, ep, ids)
        return theta

    def _finish(self, worlds: list, ids: np.ndarray, G: np.ndarray | None = None):
        """``VSWristEnv._finish_step`` of the live worlds (``ids``: their indices in the batch): the simulators'
        reads come gathered in ``G`` (rows of ``batch_sim.gather_plan``, filled by the compiled advance; None:
        gathered here); the clock, the contact record, the measures' math, the task's hooks (in the single env's
        order), rewards, observation and info run over arrays."""
        first = worlds[0]
        task = type(first)
        L = len(worlds)
        dt = first.ctrl_dt
        light = first._light_sync
        bsim = self.batch_sim
        noise = first._noise_std is not None
        hook_contact = self._hook_contact
        # the clock (``VSWristEnv._tick``) of every world, before any task hook reads it
        ep = self._ep
        A = ep.action[ids]
        steps, t = tick(ep.step[ids], dt)
        ep.put(ids, step=steps, t=t)
        # the observation's sensor noise (``_draw_noise``), before the hooks: a task's own terms may read it
        NZ = None
        if noise:
            NZ = ep.noise[ids, steps]
            ep.put(ids, nz=NZ)
        # the task's contact force (``_measure``'s hook)
        contact = task._contact_force_worlds(worlds, ep, ids) if hook_contact else np.zeros(L)
        sims = [e.sim for e in worlds]
        redo = np.flatnonzero(ep.diverged[ids]).tolist()
        for k in redo:  # MuJoCo reset this world's state: bring it up to date as _measure does
            if light:
                sims[k].sync_kinematics()
            sims[k].posture()
        if G is None:
            G = bsim.gather(sims)
        elif redo:
            G[redo] = bsim.gather([sims[k] for k in redo])
        P, D, Q = bsim.read_posture(G)
        failures = step_failures({k: worlds[k]._sim_error for k in redo}, P, D, t)
        closure = bsim.read_closure(G, sims)
        restart_failed(worlds, failures, closure)
        for k in failures:  # what the restarted worlds' observations read: their clean state (``_measure``'s row)
            e = worlds[k]
            P[k], D[k], contact[k] = e._posture, e._defl, e._contact
            G[k] = bsim.gather([e.sim])[0]
            Q[k] = bsim.qpos(G[k:k + 1])[0]
        law = SpringLaw(ep.spring_K[ids][:, None], ep.spring_delta0[ids][:, None])  # each world's own springs
        energy = stored_energy(D, law)
        T = ep.references[ids, steps]  # the step's row of each world's reference table
        err = wrap_angle(P - T)
        closure_a = np.array(closure)
        # the contact record (``VSWristEnv._record_step``), over arrays
        peak, sumsq = record_contact(ep.peak_contact[ids], ep.sum_contact_sq[ids], contact)
        # the measures and the record into the worlds' rows, before the task hooks below read them
        ep.put(ids, posture=P, defl=D, energy=energy, contact=contact, closure=closure_a, peak_contact=peak,
               sum_contact_sq=sumsq, target=T)
        record_history(ep, ids, steps, err)
        lam = ep.lam[ids]
        prev = ep.prev_action[ids]
        terminated = np.zeros(L, dtype=bool)
        terminated[list(failures)] = True
        PA = A.astype(np.float32)
        time_up, cut, truncated = episode_end(terminated, steps, first.episode_steps, closure_a, first._closure_warn,
                                              first._closure_truncate)

        # the task's reward terms
        task_terms = task._task_reward_terms_worlds(worlds, ep, ids, err) if self._hook_reward else {}
        # after the reward hooks, as the single env's _finish_step
        ep.put(ids, prev_action=PA, ended=terminated | truncated)

        # reward (the single env's, over arrays)
        cols, reward = first._step_reward(err, energy, A, prev, terminated, task_terms)

        # observation (the single env's terms, over arrays)
        measures = BatchMeasures(worlds, ep.task, ids, bsim, G, P, D, Q, law, contact, lam, PA, T, steps, t, NZ)
        obs = observe(first.obs_terms, measures, *first._obs_bounds)

        # info (the single env's metrics, over arrays)
        success = np.zeros(L, dtype=bool)
        final = np.flatnonzero(time_up & ~cut)
        if final.size:
            success[final] = task._success_worlds([worlds[k] for k in final.tolist()], ep, ids[final])
        cols.update(step_metrics(err, contact, peak, sumsq, steps, energy, lam, closure_a,
                                 first._closure_warn, t, success))
        if self._hook_info:
            cols.update(task._task_info_worlds(worlds, ep, ids))
        cols["posture_error_vec"] = err
        return obs, reward, terminated, truncated, cols, failures
