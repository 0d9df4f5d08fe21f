"""The best constant stiffness on the same episodes: what every printed score of a trained agent stands beside.

A trained agent's return means little alone: the question the benchmark asks is whether it beats the analytic
agent at the best fixed stiffness command. `best_constant` evaluates the analytic agent at each of the levels
`vswrist compare` uses (DEFAULT_STIFFNESS_LEVELS) on exactly the episodes the agent met (same reset seeds, same
task settings; the analytic agent acts through its own action mode), picks the level with the highest mean
return, and `paired_difference` gives the agent's return minus the baseline's, episode by episode, with its
Student-t interval. The best level is picked on these same episodes, which favours the baseline slightly: a
difference above zero is a conservative verdict for the agent. The analytic agent has no network, and a seed's
episodes run as the worlds of one batch, so this costs five analytic evaluations.
"""

from __future__ import annotations

import math

import numpy as np

DEFAULT_STIFFNESS_LEVELS = (-1.0, -0.5, 0.0, 0.5, 1.0)  # vswrist compare's fixed-stiffness levels


ACTION_KEYS = ("action_mode", "residual")  # how an agent's actions map to commands: the agent's, not the task's


def task_env_kwargs(env_kwargs: dict | None) -> dict:
    """A trained agent's env_kwargs without its action interface (action mode, residual scales): the analytic
    agent commands the task through its own posture-and-stiffness mode on the same task and episodes, as
    `vswrist compare` and the shipped policies' cards run it."""
    kwargs = {k: v for k, v in (env_kwargs or {}).items() if k not in ACTION_KEYS}
    if isinstance(kwargs.get("config"), dict):
        kwargs["config"] = {k: v for k, v in kwargs["config"].items() if k not in ACTION_KEYS}
    return kwargs


def _analytic(stiffness: float):
    from vswrist_gym.agents.analytic import AnalyticAgent

    return lambda env: AnalyticAgent(env, stiffness=stiffness)


def best_constant(env_id: str, seeds, episodes: int, env_kwargs: dict | None = None,
                  levels=DEFAULT_STIFFNESS_LEVELS) -> dict | None:
    """{'label', 'stiffness', 'records', 'returns'} of the fixed stiffness with the highest mean return on the
    protocol's episodes of `seeds` (`env_kwargs`: the agent's, see task_env_kwargs); None when the task cannot run
    the analytic agent (no posture reference)."""
    from vswrist_gym.agents.protocol import evaluate

    best = None
    for k in levels:
        try:
            records, _ = evaluate(env_id, _analytic(k), seeds, episodes, env_kwargs=task_env_kwargs(env_kwargs))
        except ValueError:  # the observation has no 'target' term: no analytic agent on this task
            return None
        mean = float(np.mean([r["return"] for r in records]))
        if best is None or mean > best["mean_return"]:
            best = {"label": f"analytic:{k:+.2f}", "stiffness": float(k), "records": records, "mean_return": mean}
    return best


def best_constant_episode(env_id: str, seed: int, env_kwargs: dict | None = None,
                          levels=DEFAULT_STIFFNESS_LEVELS) -> tuple[str, float] | None:
    """(label, return) of the best fixed stiffness on one episode reset with `seed` (what `vswrist video` shows);
    None when the task cannot run the analytic agent."""
    import gymnasium as gym

    from vswrist_gym.agents.protocol import run_episode

    best = None
    env = gym.make(env_id, **task_env_kwargs(env_kwargs))
    try:
        for k in levels:
            try:
                agent = _analytic(k)(env)
            except ValueError:
                return None
            ret = run_episode(env, agent, seed)[0]["return"]
            if best is None or ret > best[1]:
                best = (f"analytic:{k:+.2f}", float(ret))
    finally:
        env.close()
    return best


def paired_difference(records: list[dict], baseline: list[dict], metric: str = "return") -> dict:
    """The agent's `metric` minus the baseline's on the same episodes (matched by reset seed): mean and Student-t
    95 % interval over the episodes."""
    from vswrist_gym.agents.protocol import mean_ci

    base = {r["reset_seed"]: r[metric] for r in baseline}
    diffs = [r[metric] - base[r["reset_seed"]] for r in records if r["reset_seed"] in base]
    return mean_ci([d for d in diffs if d is not None and not math.isnan(d)])


def baseline_summary(records: list[dict], best: dict) -> dict:
    """What evaluate stores and prints: the best constant's label, its return summary and the paired difference."""
    from vswrist_gym.agents.protocol import summarise

    return {"label": best["label"], "stiffness": best["stiffness"], "return": summarise(best["records"])["return"],
            "paired_difference_return": paired_difference(records, best["records"])}


def format_baseline(doc: dict) -> str:
    """Two lines: the best constant's return and the paired difference, with their intervals."""
    r, d = doc["return"], doc["paired_difference_return"]

    def ci(s):
        return "" if s["low"] != s["low"] else f" [{s['low']:.4g}, {s['high']:.4g}]"

    verdict = ("n/a" if d["low"] != d["low"] else "above the best constant" if d["low"] > 0 else
               "below the best constant" if d["high"] < 0 else "not distinguishable from the best constant")
    return (f"best constant stiffness on the same episodes: {doc['label']}, return {r['mean']:.4g}{ci(r)}\n"
            f"paired difference in return (agent - best constant, over {d['n']} episodes): "
            f"{d['mean']:+.4g}{ci(d)}: {verdict}")
