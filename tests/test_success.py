"""Each task's ``is_success`` means what the task means: flailing does not succeed more often than the analytic
baseline, and an agent that does the task succeeds on some episodes (so each test can fail both ways).

Why N = 10 episodes and these comparisons are enough (2026-12-02, this 2-core dev machine): in
``python -m vswrist_gym.tools.probe --success --episodes 100`` uniform random and bang-bang actions succeed in none
of 100 episodes on any task, and over 100 episodes per agent (a one-off script, the threshold over the metric of
each task's criterion for the closest episode) they came no closer than 0.16 of the way to a threshold in the
default mode and 0.37 in the residual mode (Insertion excepted, below): random actions that seat Insertion's pin
hit the walls with 428 N and more against the 40 N limit. A success of a flailing agent on another machine
(MuJoCo's rounding differs, chaotic trajectories diverge) would need an episode several times better than any of
100 seen here, so 0 of 10 is what to expect, and "not above the baseline" holds even where the baseline succeeds
in none (LoadHold, Drill: their best-return constant is above the energy bound; Insertion: the softest constant
cannot push past the fit).

The agents that do succeed (seeds 1000-1019, ``probe --success --episodes 20``): Insertion the rule 20/20, Polish
the rule 17/20 (its force averaged over the control period), Impact the baseline 17/20, Drill the oracle 17/20,
LoadHold the constant s = 0 8/20; the test asks for one success in 10. Hammer's flailing is tested in
tests/test_hammer.py (none of its flailing agents may succeed: its best constant does on some episodes).

Residual-mode random actions (the baseline's reference dithered) are not asserted on Insertion: dithering can
push the pin past the fit with moderate wall force, and one of 100 such episodes seated the pin with a peak wall
force of 40.9 N, 2 % above the limit (``probe --success --tasks Insertion --episodes 100``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym
from vswrist_gym.tools.probe import adaptive_policy, constant_policy, evaluate, oracle_policy, random_policy

N = 10
SEEDS = range(1000, 1000 + N)

# the agent that does the task on some episodes: (name, factory(env))
COMPETENT = {
    "Insertion": ("rule", adaptive_policy),
    "Polish": ("rule", adaptive_policy),
    "Impact": ("baseline", None),
    "Drill": ("oracle", oracle_policy),
    "LoadHold": ("s=0", lambda env: constant_policy(env, 0.0)),
}


def _rate(env, factory) -> float:
    return evaluate(env, factory, SEEDS)[1]


def _baseline(env):
    """The analytic baseline: the task's reference at its residual.stiffness_nominal (= the zero residual action)."""
    return lambda: constant_policy(env, env.unwrapped.cfg["residual"]["stiffness_nominal"])


@pytest.mark.parametrize("task", list(COMPETENT))
def test_flailing_does_not_beat_the_analytic_baseline(task):
    env = gym.make(vswrist_gym.LATEST[task])
    baseline = _rate(env, _baseline(env))
    rates, deepest = {}, []
    u = env.unwrapped

    def flail(bang):
        act = random_policy(env, rng, bang)
        deepest.append(0.0)

        def policy(obs):
            if task == "Insertion":
                deepest[-1] = max(deepest[-1], u.pin_depth())
            return act(obs)
        return policy

    for label, bang in (("random", False), ("bang-bang", True)):
        rng = np.random.default_rng(0)
        rates[label] = _rate(env, lambda b=bang: flail(b))
    if task == "Insertion":
        # the flailing does reach the depth: a depth-only criterion (the largest depth reaching success_depth)
        # counted 81 % of random and 64 % of bang-bang episodes as successes over 100 episodes, and 18 of these
        # 20; this test fails on such a criterion. 0.3 leaves room for another machine's trajectories.
        reached = np.mean(np.array(deepest) >= u.tp["success_depth"] * u.tp["hole_depth"])
        assert reached >= 0.3, f"flailing reached the success depth in only {reached:.0%} of the episodes"
    if task != "Insertion":  # see the module docstring
        res = gym.make(vswrist_gym.LATEST[task], config={"action_mode": "residual"})
        for label, bang in (("random (residual)", False), ("bang-bang (residual)", True)):
            rng = np.random.default_rng(0)
            rates[label] = _rate(res, lambda b=bang: random_policy(res, rng, b))
        res.close()
    name, factory = COMPETENT[task]
    competent = baseline if factory is None else _rate(env, lambda: factory(env))
    env.close()
    for label, r in rates.items():
        assert r <= baseline, f"{task}: {label} actions succeed in {r:.0%} of {N} episodes, the baseline in {baseline:.0%}"
    assert competent >= 1.0 / N, f"{task}: the {name} agent succeeds in none of {N} episodes"
