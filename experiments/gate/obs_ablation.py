"""Diagnostic (not part of the gate): which observations does a posture-only PPO's gain rest on?

The seed-0 posture-only PPO of `vswrist gate` (runs/gate/<Task>-vN/seed0) is run on tuning episodes
(TUNING_EVAL_SEEDS[:2] x 10, as ``trim_diagnostic.py``; no held-out episode is read), once as trained and once per
group of observation terms held at their value of the episode's first observation (the policy then cannot see
how they change). Printed per task and group: its mean paired gain over the selected constant (standard error).
A gain that collapses when a group is frozen rests on that group.

    PYTHONPATH=. python experiments/gate/obs_ablation.py [TASK_ID ...]
"""

import json
import sys
from pathlib import Path

import numpy as np

from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS
from vswrist_gym.tools import gate

SEEDS, EPISODES = TUNING_EVAL_SEEDS[:2], 10
GROUPS = {
    "none": (),
    "tool_wrench": ("tool_wrench",),
    "cue": ("engage_cue", "load_cue"),
    "springs": ("deflections", "spring_torques", "stiffness", "lam", "motor_angles"),
    "posture": ("posture", "posture_rate"),
    "all sensing": ("tool_wrench", "deflections", "spring_torques", "stiffness", "lam", "motor_angles", "posture",
                    "posture_rate", "contact_force"),
}


class Frozen:
    """The agent with the observation entries of ``names`` held at the episode's first observation."""

    def __init__(self, agent, env, names):
        sl = env.unwrapped.obs_slices
        self.agent, self.idx = agent, np.concatenate([np.arange(sl[n].start, sl[n].stop) for n in names if n in sl]
                                                     or [np.zeros(0, dtype=int)])
        self.first = None

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        obs = np.array(obs, dtype=np.float32, copy=True)
        start = episode_start is not None and bool(np.asarray(episode_start).reshape(-1)[0])
        if self.first is None or start:
            self.first = obs.copy()
        obs[..., self.idx] = self.first[..., self.idx]
        return self.agent.predict(obs, state=state, episode_start=episode_start, deterministic=True)


def main(ids):
    for env_id in ids:
        doc = json.loads(gate.result_path(Path("experiments/gate"), env_id).read_text())
        best = doc["selection"]["best_constant"]
        spec = AgentSpec(str(Path(doc["necessity"]["runs"]["0"]["run_dir"])), checkpoint="final")
        const = np.array(gate.episode_returns(env_id, gate.constant_agent(best), SEEDS, EPISODES, {"config": {}}))
        for name, terms in GROUPS.items():
            ppo = np.array(gate.episode_returns(env_id, lambda env, t=terms: Frozen(spec.make(env), env, t), SEEDS,
                                                EPISODES, spec.env_kwargs))
            d = gate.paired(ppo, const)
            print(f"{env_id}: posture-only PPO seed 0, frozen {name:>11}: {d['mean']:+.1f} ({d['se']:.1f}) over "
                  f"s = {best:+.1f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["VSWrist/Drill-v2"])
