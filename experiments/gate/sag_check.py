"""Diagnostic (not part of the gate): does a fixed posture trim still gain, and does the stiffness rule still gain?

Tuning episodes only (TUNING_EVAL_SEEDS; no held-out episode is read), split in two: every candidate is scored on
the first half (seeds 2048-2052 x 10 episodes) and the chosen one is measured, paired against the chosen constant,
on the second half (2053-2057 x 10), so that the reported gains are not the maxima of the episodes they were
chosen on.

* best constant: the reference agent at each of the gate's five commands;
* fixed trim: the residual mode at that constant with a constant posture action, a RUD offset of -0.06 to +0.06
  rad in steps of 0.01 (FE and PS trims 0; the trims ``trim_diagnostic.py`` found were RUD);
* rule: the gate's observation-only rule (``gate.rule_agent``) at each of its ten (soft, stiff) pairs.

    PYTHONPATH=. python experiments/gate/sag_check.py [TASK_ID ...] [--config JSON]
"""

import json
import sys

import numpy as np

from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS
from vswrist_gym.tools import gate
from vswrist_gym.tools.probe import CONSTANT_COMMANDS

CHOOSE, MEASURE, EPISODES = TUNING_EVAL_SEEDS[:5], TUNING_EVAL_SEEDS[5:], 10
TRIMS = np.round(np.arange(-0.06, 0.0601, 0.01), 3)
SCALE = 0.15  # rad per unit posture action (the gate's posture-only residual)


class Fixed:
    def __init__(self, a):
        self.a = np.asarray(a, dtype=np.float32)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.a, None


CONFIG: dict = {}  # --config JSON: settings over the id's (an exploratory task change)


def trim_kwargs(c):
    return {"config": {**CONFIG, "action_mode": "residual",
                       "residual": {"posture_scale": SCALE, "stiffness_scale": 0.0, "stiffness_nominal": float(c)}}}


def trim_agent(rud):
    return lambda env: Fixed([rud / SCALE, 0.0, 0.0, 0.0])


def main(ids):
    for env_id in ids:
        run = lambda make, seeds, kw=None: np.array(  # noqa: E731
            gate.episode_returns(env_id, make, seeds, EPISODES, kw or {"config": dict(CONFIG)}))
        const = {c: run(gate.constant_agent(c), CHOOSE) for c in CONSTANT_COMMANDS}
        c = max(const, key=lambda k: const[k].mean())
        trims = {t: run(trim_agent(t), CHOOSE, trim_kwargs(c)) for t in TRIMS}
        t = max(trims, key=lambda k: trims[k].mean())
        rules = {lv: run(gate.rule_agent(lv), CHOOSE) for lv in gate.RULE_LEVELS}
        lv = max(rules, key=lambda k: rules[k].mean())
        base = run(gate.constant_agent(c), MEASURE)
        trim = gate.paired(run(trim_agent(t), MEASURE, trim_kwargs(c)), base)
        rule = gate.paired(run(gate.rule_agent(lv), MEASURE), base)
        print(f"{env_id}: best constant s = {c:+.1f} ({base.mean():.1f}); fixed RUD trim {t:+.2f} rad: "
              f"{trim['mean']:+.1f} (s.e. {trim['se']:.1f}); rule {lv}: {rule['mean']:+.1f} (s.e. {rule['se']:.1f}) "
              f"over the constant, 50 episodes", flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    if "--config" in args:
        k = args.index("--config")
        CONFIG.update(json.loads(args[k + 1]))
        del args[k:k + 2]
    main(args or ["VSWrist/Impact-v0", "VSWrist/Impact-v1", "VSWrist/Drill-v1", "VSWrist/Drill-v2",
                          "VSWrist/LoadHold-v1"])
