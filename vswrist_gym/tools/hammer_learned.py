"""Hammer: trained policies' strike speed against the optimised open-loop stiffness schedule and the best constant
stiffness, on the same held-out episodes (the target: a learned schedule within 10 % of the optimised one), on
the Hammer id the agents were trained on.

    python -m vswrist_gym.tools.hammer_learned --agent pretrained:Hammer:stiffness [--agent RUN_DIR ...]
                                               [--episodes 12] [--seed0 1000] [--json PATH]

The constants, the rule and the optimised schedule are the probe's (``tools.probe``: the schedule is optimised
on training seeds 100-105, so the episodes ``seed0 ...`` are held out); every agent runs the same episodes
(reset seeds) in the environment it was trained in (its own action mode and normalisation). Speeds are the
head's speed normal to the anvil at the strike (m/s); a miss counts in ``strikes`` and is left out of the means
and of the paired differences.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

TASK = "Hammer"


def trained_id(text: str) -> str:
    """The Hammer id agent ``text`` was trained on (every agent of a comparison must share it)."""
    from vswrist_gym.agents.evaluate import AgentSpec

    spec = AgentSpec(text)
    env_id = spec.trained.env_id if spec.trained is not None else None
    if not (env_id or "").startswith(f"VSWrist/{TASK}-"):
        raise ValueError(f"{text}: a policy trained on a {TASK} id is needed, got {env_id}")
    return env_id


def agent_speeds(text: str, seeds, env_id: str) -> list[float]:
    """Strike speed of agent ``text`` (``vswrist evaluate``'s ``--agent`` syntax) on each reset seed of ``env_id``
    (NaN: a miss)."""
    import gymnasium as gym

    from vswrist_gym.agents.evaluate import AgentSpec
    from vswrist_gym.agents.protocol import run_episode

    spec = AgentSpec(text)
    spec.check_task(env_id)
    env = gym.make(env_id, **spec.env_kwargs)
    try:
        agent = spec.make(env)
        out = []
        for s in seeds:
            record, _ = run_episode(env, agent, int(s))
            v = record["impact_speed"]
            out.append(v if v > 0.0 else math.nan)
        return out
    finally:
        env.close()


def paired(a: list[float], b: list[float]) -> tuple[float, float, int]:
    """Mean and standard error of a - b over the episodes where both struck, and their count."""
    d = np.array(a) - np.array(b)
    d = d[np.isfinite(d)]
    se = float(d.std(ddof=1) / math.sqrt(len(d))) if len(d) > 1 else math.nan
    return (float(d.mean()) if len(d) else math.nan), se, len(d)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vswrist_gym.tools.hammer_learned", description=__doc__.split("\n\n")[0])
    p.add_argument("--agent", action="append", required=True, help="an agent as in vswrist evaluate (repeatable)")
    p.add_argument("--episodes", type=int, default=12, help="held-out episodes (default 12)")
    p.add_argument("--seed0", type=int, default=1000, help="first reset seed (default 1000, the probe's)")
    p.add_argument("--json", default=None, help="also write the speeds as JSON")
    args = p.parse_args(argv)
    if args.episodes < 2:
        p.error("--episodes must be >= 2 (a paired standard error needs two episodes)")

    from vswrist_gym.agents.hparams import ConfigError
    from vswrist_gym.agents.fileio import RunDirError
    from vswrist_gym.tools.probe import probe

    seeds = list(range(args.seed0, args.seed0 + args.episodes))
    try:
        ids = {a: trained_id(a) for a in args.agent}
        if len(set(ids.values())) > 1:
            raise ValueError(f"the agents were trained on different ids: {ids}")
        env_id = next(iter(ids.values()))
        learned = {a: agent_speeds(a, seeds, env_id) for a in args.agent}
    except (ConfigError, RunDirError, FileNotFoundError, ValueError) as exc:
        p.error(str(exc))
    r = probe(env_id, args.episodes, seed0=args.seed0)
    speeds = r["impact_speed"]
    best = f"s={r['best_constant']:+.1f}"
    rows = {f"best constant ({best})": speeds[best], "rule": speeds["rule"], "optimised schedule": speeds["oracle"],
            **learned}
    rigid = float(np.mean(r["rigid_speed"]))
    sched = speeds["oracle"]
    m_sched = float(np.nanmean(sched))
    print(f"{env_id}, {args.episodes} held-out episodes (reset seeds {seeds[0]}-{seeds[-1]}); "
          f"rigid bound {rigid:.2f} m/s")
    print(f"{'agent':<38}{'speed m/s':>10}{'x rigid':>8}{'/ schedule':>11}{'- schedule (s.e.)':>20}{'strikes':>9}")
    doc = {"task": env_id, "seeds": seeds, "rigid_speed": rigid, "rows": {}}
    for label, v in rows.items():
        m = float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
        d, se, n = paired(v, sched)
        hits = int(np.isfinite(v).sum())
        print(f"{label:<38}{m:>10.2f}{m / rigid:>8.2f}{m / m_sched:>11.3f}{d:>+12.2f} ({se:.2f})"
              f"{hits:>6}/{len(v)}")
        doc["rows"][label] = {"speeds": [None if math.isnan(x) else x for x in v], "mean": m,
                              "ratio_to_schedule": m / m_sched, "paired_minus_schedule": [d, se, n]}
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=2))
    return 0


if __name__ == "__main__":
    from vswrist_gym.cli import run_tool

    raise SystemExit(run_tool(main))
