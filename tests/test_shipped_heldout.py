"""No shipped policy loses to the best constant stiffness on held-out episodes.

The constant is the one the task's validity gate selected on tuning episodes (experiments/gate/<Task>-vN.json);
policy and constant run the same held-out episodes (protocol.HELDOUT_EVAL_SEEDS), and a policy fails when the
95 % Student-t interval of the paired difference lies below zero. The default suite runs the first 5 episodes
of the first held-out seed (a smoke test of the claim); the `slow` test runs all 100, the claim the cards make."""

from pathlib import Path

import pytest

from vswrist_gym.agents.protocol import HELDOUT_EVAL_SEEDS
from vswrist_gym.agents.shipped import shipped
from vswrist_gym.tools.gate import shipped_against_constant

GATE = Path(__file__).resolve().parents[1] / "experiments" / "gate"
SHIPPED = sorted(shipped())
IDS = [f"{task}:{track}" for task, track in SHIPPED]


@pytest.mark.parametrize("key", SHIPPED, ids=IDS)
def test_shipped_policy_does_not_lose_on_five_heldout_episodes(key):
    r = shipped_against_constant(*key, GATE, episodes_per_seed=5, seeds=HELDOUT_EVAL_SEEDS[:1])
    assert r["difference"]["n"] == 5
    assert not r["loses"], r


@pytest.mark.slow
@pytest.mark.parametrize("key", SHIPPED, ids=IDS)
def test_shipped_policy_does_not_lose_on_the_heldout_episodes(key):
    r = shipped_against_constant(*key, GATE)
    assert r["difference"]["n"] == len(HELDOUT_EVAL_SEEDS) * 10
    assert not r["loses"], r
