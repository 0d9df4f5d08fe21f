"""Each task's ``is_success`` means what the task means: flailing does not succeed more often than the analytic
baseline, and an agent that does the task succeeds on some episodes (so each test can fail both ways).

Why N = 10 episodes and these comparisons are enough (``python -m vswrist_gym.envs.probe --success``, and the
closeness of flailing to success measured over 100 episodes per agent, 2026-12-02, this 2-core dev machine):
uniform random and bang-bang actions (the default ``posture_stiffness`` mode) succeeded in 0 of 100 episodes on
every task, and in no episode did they come within a factor 6 of a success threshold (the closest: 0.16 of the
way, measured as threshold over metric, e.g. Insertion's wall-force limit over the peak wall force of an episode
that seated the pin: random actions that seat the pin hit the walls with 400 N and more). So a success of a
flailing agent on another machine (MuJoCo's rounding differs, chaotic trajectories diverge) would need an
episode many times better than any of 100 seen here: 0 of 10 is the expected outcome, and the assertion
"not above the baseline" holds even where the baseline succeeds in 0 (LoadHold, Drill, Insertion: their
best-return constant stiffness exceeds the energy bound, or cannot push past Insertion's fit).

The agents that succeed (rate on seeds 1000-1019, probe --success): Insertion the rule 1.00, Polish the rule 0.65,
Impact the baseline 0.85, Drill the oracle 0.85, LoadHold the constant s = 0 0.40; the test asks for one success
in 10.

Residual-mode random actions (the baseline plus noise) are not asserted on Insertion: dithering the baseline's
reference can push the pin past the fit with moderate wall force, and one of 100 such episodes came within 2 % of
the 40 N limit (0 successes in 100); they are reported by the probe. On the other tasks they stay at most 0.37
of the way to a success in 100 episodes, and are tested.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import vswrist_gym  # noqa: F401
from vswrist_gym.envs.probe import adaptive_policy, constant_policy, evaluate, oracle_policy, random_policy

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
    env = gym.make(f"VSWrist/{task}-v0")
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
        res = gym.make(f"VSWrist/{task}-v0", config={"action_mode": "residual"})
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
