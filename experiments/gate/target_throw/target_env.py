"""A probe task, not registered in the package: Throw-v0's wind-up and throw, but each episode asks for a release
speed, observed, instead of the fastest one.

After Braun et al. (Autonomous Robots 2012; IEEE T-RO 2013), whose speed-limited, spring-driven arm throws for
distance, and the throwing-to-a-target setting of TossingBot (Zeng et al., RSS 2019): the agent must meter the energy
the springs store and return, not maximise it. The target, ``target_ratio`` (drawn per episode, observed as
``target_speed``), is the release speed in units of the episode's rigid bound (motor speed limit x lever), so the
same target asks for the same springs' share on every ball; its range spans what the stiffest constant gives (about
1.55) to what only a wind-up schedule reaches (about 2.75). The ball, the counter-movement and the release are
Throw-v0's, drawn from the same seed in the same order (the target is drawn after them), so that Throw-v0's agents
release at the same speeds here.

Reward (the ``throw`` term, at a timely release): a tent, 1 at the target and 0 from ``target_tolerance`` x the
rigid bound away (a basket, not a ruler: a throw that misses by a tolerance scores as one that falls short by a
metre), weighted 100; the miss, the preload energy and the action rate are Throw-v0's. Success: a timely release within half the
tolerance of the target, in the swing's plane as in Throw-v0.
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.envs.registration import register

from vswrist_gym.envs.episode import episode_history, task_field
from vswrist_gym.envs.shared import off_plane
from vswrist_gym.envs.throw import ThrowEnv

ENV_ID = "VSWrist/ProbeThrowTarget-v0"
# Throw-v0's observation with the target; the target's range and the tent's half-width
# ``throw`` 100 per full score: a good throw is worth what Throw-v0's is (about 10 per m/s, 90-110 an episode), so
# the preload energy weighs as little as it does there
ID_CONFIG = {"task": {"target_ratio": [1.55, 2.75], "target_tolerance": 0.2}, "reward": {"throw": 100.0},
             "observation": ["posture", "posture_rate", "motor_angles", "deflections", "spring_torques", "stiffness",
                             "lam", "prev_action", "target", "tool_wrench", "released", "phase", "target_speed"]}


class ThrowTargetEnv(ThrowEnv):
    task_id = ENV_ID
    task_spec = {**ThrowEnv.task_spec, "target_ratio": ("interval", 0.0, 10.0),
                 "target_tolerance": ("number", 1e-3, 10.0)}

    @property
    def task_state(self) -> dict:
        return {**super().task_state, "target": ((), float)}

    def _task_obs_terms(self):
        from vswrist_gym.envs.observations import ObsTerm, column
        lo, hi = self.tp["target_ratio"]
        return super()._task_obs_terms() + [ObsTerm(
            "target_speed", 1, "x rigid bound", "the release speed asked for, in units of the rigid bound", None,
            lo, hi, lambda m: column(m.state("target")))]

    def _task_reset(self, rng):
        out = super()._task_reset(rng)
        self._ep.task.put(0, target=float(rng.uniform(*self.tp["target_ratio"])))  # after Throw's draws
        return out

    def _on_release(self, st, time, vel):
        super()._on_release(st, time, vel)
        if st.timely.item(0):
            k = st.release_step.item(0)
            err = abs(st.release_speed.item(0) / st.rigid.item(0) - st.target.item(0))
            st.terms[0, k + 1, 0] = max(0.0, 1.0 - err / self.tp["target_tolerance"])

    @classmethod
    def _success_worlds(cls, worlds, ep, ids):
        tp = worlds[0].tp
        st = ep.task
        err, _, _ = episode_history(ep, ids)
        near = np.abs(st.release_speed[ids] / np.maximum(st.rigid[ids], 1e-9) - st.target[ids])
        return (st.timely[ids] & (near <= 0.5 * tp["target_tolerance"]) & (st.aim[ids] <= tp["success_aim_error"])
                & (off_plane(err, st.release_step[ids]) <= tp["success_plane_error"]))

    @classmethod
    def _task_info_worlds(cls, worlds, ep, ids):
        return {**super()._task_info_worlds(worlds, ep, ids), "target_ratio": ep.task.target[ids]}


def _vector(num_envs: int = 1, **kwargs):
    from vswrist_gym.envs.batch import VSWristVectorEnv
    return VSWristVectorEnv(ENV_ID, num_envs, **kwargs)


def register_probe(task: dict | None = None) -> str:
    """Register the probe id in this process (``task``: settings over ``ID_CONFIG``'s task section)."""
    if ENV_ID not in gym.registry:
        cfg = {**ID_CONFIG, "task": {**ID_CONFIG["task"], **(task or {})}}
        register(id=ENV_ID, entry_point=ThrowTargetEnv, kwargs={"id_config": cfg}, vector_entry_point=_vector)
    return ENV_ID
