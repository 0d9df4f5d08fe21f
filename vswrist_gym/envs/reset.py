"""The reset sequence of a VS-Wrist world (``VSWristEnv``'s mixin): its episode state set back, the episode's
draws, the simulator's initial state, the settling under gravity and the first measures.

A reset runs in three phases, as a step, so that a batch (``batch.VSWristVectorEnv``) settles the worlds it resets
on its threads, beside the other worlds' physics: ``_reset_begin`` (the episode's draws, the initial state and
references; over the worlds that reset together in ``_reset_begin_worlds``), ``_settle`` (the physics only:
touches nothing but this world's MjModel/MjData) and ``_reset_finish``. The single env's ``reset`` runs them in
order on its one world.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np


class ResetMixin:
    """``reset`` and its phases; ``_reset_state``: the episode state a new episode starts from."""

    def _reset_state(self) -> None:
        self._ep.clear(0)
        self._noise_std = None
        self._sim_error = None  # the simulator's message where the physics diverged (the episode state's flag)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self._reset_begin(seed)
        type(self)._reset_worlds([self])
        self._settle()
        return self._reset_finish()

    def _reset_begin(self, seed: int | None) -> None:
        type(self)._reset_begin_worlds([self], [seed])

    @classmethod
    def _reset_begin_worlds(cls, worlds: list, seeds: list) -> None:
        """``_reset_begin`` of ``worlds`` (of this task) with ``seeds``: each world's draws from its own
        generator, then the simulators' initial states in one call (``WristSim.reset_many``: the kinematics of
        all their postures over arrays, what a reset costs most)."""
        draws = []
        for e, seed in zip(worlds, seeds):
            if seed is None:
                e._rewind_unread_noise()
            gym.Env.reset(e, seed=seed)
            e._reset_state()
            e._randomize()
            u0, ps0, s0 = e._task_reset(e.np_random)
            draws.append((u0, float(ps0), float(e.stiffness_map.to_lam(s0))))
        worlds[0]._WristSim.reset_many([e.sim for e in worlds], [tuple(d[0]) for d in draws],
                                       [d[1] for d in draws], [d[2] for d in draws])
        for e, (u0, ps0, lam0) in zip(worlds, draws):
            e.ctrl.reset(posture=(float(u0[0]), float(u0[1]), ps0), lam=lam0)
            e.sim.apply_wrench(np.zeros(3), np.zeros(3))
            if e.cfg["settle_s"] > 0.0:
                e.sim.set_motor_references(e.ctrl.step(np.array([u0[0], u0[1], ps0]), lam=lam0))

    def _settle(self) -> None:
        """Let the wrist settle under gravity at the initial references (the simulator starts at rest at the
        exact posture, which is not an equilibrium once the hand's and the tool's weight act)."""
        if self.cfg["settle_s"] > 0.0:
            self.sim.step(self._settle_steps * self.model.opt.timestep)

    def _reset_finish(self):
        self._after_reset()
        # the episode's references at every control instant k ctrl_dt, in one array call (the same times as
        # ``_step * ctrl_dt``): a step reads its row, in a batch as alone
        ep = self._ep
        ep.references[0] = self._reference(np.arange(self.episode_steps + 1) * self.ctrl_dt)
        ep.target[0] = ep.references[0, 0]
        self._measure()
        ep.closure[0] = self.sim.loop_closure_peak() if self.cfg["settle_s"] > 0.0 else \
            self.sim.loop_closure_error()
        ep.ended[0] = False
        self._draw_noise_table()
        if self.cfg["action_mode"] == "residual":
            ep.prev_action[0] = 0.0
        return self._observation(), self._info({}, final=False)
