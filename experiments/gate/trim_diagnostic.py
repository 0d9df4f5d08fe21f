"""Diagnostic (not part of the gate): how much of the posture-only PPO's gain is a constant posture offset?

For each task, the seed-0 posture-only PPO of `vswrist gate` (runs/gate/<Task>-vN/seed0) is run on tuning episodes
(TUNING_EVAL_SEEDS[:2] x 10; no held-out episode is read); its mean action over all steps is then applied as a
constant residual (a fixed posture trim, the stiffness still at the selected constant). Printed per task: the
PPO's and the fixed trim's mean paired gain over the selected constant (with standard errors), the fixed trim
(rad), and the within-episode s.d. of the PPO's posture actions (rad).

    python experiments/gate/trim_diagnostic.py [TASK_ID ...]
"""

import json
import sys
from pathlib import Path

import numpy as np

from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS
from vswrist_gym.tools import gate

SEEDS, EPISODES = TUNING_EVAL_SEEDS[:2], 10


class Recorder:
    def __init__(self, agent):
        self.agent, self.actions = agent, []

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        a, s = self.agent.predict(obs, state=state, episode_start=episode_start, deterministic=True)
        self.actions.append(np.asarray(a, dtype=float).reshape(-1))
        return a, s


class Fixed:
    def __init__(self, a):
        self.a = np.asarray(a, dtype=np.float32)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.a, None


def main(ids):
    for env_id in ids:
        doc = json.loads(gate.result_path(Path("experiments/gate"), env_id).read_text())
        best = doc["selection"]["best_constant"]
        run = Path(doc["necessity"]["runs"]["0"]["run_dir"])
        spec = AgentSpec(str(run), checkpoint="final")
        scale = spec.env_kwargs["residual"]["posture_scale"]
        const = np.array(gate.episode_returns(env_id, gate.constant_agent(best), SEEDS, EPISODES, {"config": {}}))
        rec = Recorder(None)

        def make(env):
            rec.agent = spec.make(env)
            return rec
        ppo = np.array(gate.episode_returns(env_id, make, SEEDS, EPISODES, spec.env_kwargs))
        acts = np.array(rec.actions)
        n = len(acts) // (len(SEEDS) * EPISODES)
        per_ep = acts[: n * len(SEEDS) * EPISODES].reshape(len(SEEDS) * EPISODES, n, -1)
        mean = acts.mean(axis=0)
        fixed = np.array(gate.episode_returns(env_id, lambda env: Fixed(mean), SEEDS, EPISODES, spec.env_kwargs))
        p, f = gate.paired(ppo, const), gate.paired(fixed, const)
        print(f"{env_id}: PPO {p['mean']:+.1f} ({p['se']:.1f}), fixed trim {f['mean']:+.1f} ({f['se']:.1f}) over "
              f"s = {best:+.1f}; trim (RUD, FE, PS) = {np.round(mean[:3] * scale, 3).tolist()} rad; within-episode "
              f"s.d. {np.round(per_ep[:, :, :3].std(axis=1).mean(axis=0) * scale, 3).tolist()} rad", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["VSWrist/LoadHold-v0", "VSWrist/Polish-v1", "VSWrist/Impact-v0", "VSWrist/Insertion-v0",
                          "VSWrist/Drill-v0"])
