"""Diagnostic (run before the gate had its posture-feedback test, whose agent is this one): can a posture feedback
stand in for the stiffness where a learner did not?

A hand-written posture-only agent at the constant stiffness (the gate's residual mode, stiffness held, 0.15 rad
posture residual): an integral trim on the measured RUD/FE error, trim <- trim - k ctrl_dt (posture - target),
clipped to the residual's range, switched on with the task's cue (``load_cue``/``engage_cue``) or from the start
where there is none. The gain k is chosen among ``GAINS`` on the first half of the tuning episodes (2048-2052 x 10)
and measured, paired against the constant and beside the gate's rule at the given levels, on the second half
(2053-2057 x 10); no held-out episode is read.

    PYTHONPATH=. python experiments/gate/posture_feedback_check.py TASK_ID CONSTANT SOFT STIFF
"""

import sys

import numpy as np

from vswrist_gym.agents.protocol import TUNING_EVAL_SEEDS
from vswrist_gym.tools import gate
from vswrist_gym.tools.gate import IntegralTrim

CHOOSE, MEASURE, EPISODES = TUNING_EVAL_SEEDS[:5], TUNING_EVAL_SEEDS[5:], 10
GAINS = gate.FEEDBACK_GAINS


def main(argv):
    env_id, c, soft, stiff = argv[0], float(argv[1]), float(argv[2]), float(argv[3])
    kw = gate.feedback_kwargs(c)
    run = lambda make, seeds, k=None: np.array(gate.episode_returns(env_id, make, seeds, EPISODES, k or {}))  # noqa
    const_c = run(gate.constant_agent(c), CHOOSE, {"config": {}})
    scores = {g: gate.paired(run(lambda env, g=g: IntegralTrim(env, g), CHOOSE, kw), const_c)["mean"]
              for g in GAINS}
    k = max(scores, key=scores.get)
    const = run(gate.constant_agent(c), MEASURE, {"config": {}})
    fb = gate.paired(run(lambda env: IntegralTrim(env, k), MEASURE, kw), const)
    rule = gate.paired(run(gate.rule_agent((soft, stiff)), MEASURE, {"config": {}}), const)
    print(f"{env_id}: s = {c:+.1f}; integral posture trim, gains {dict((g, round(v, 1)) for g, v in scores.items())} "
          f"on the first half, k = {k:g}/s: {fb['mean']:+.1f} (s.e. {fb['se']:.1f}); rule ({soft:+.1f}, {stiff:+.1f}) "
          f"{rule['mean']:+.1f} (s.e. {rule['se']:.1f}) over the constant, second half (50 episodes)", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
