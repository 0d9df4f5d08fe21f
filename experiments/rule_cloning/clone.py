"""Behaviour cloning of each gated task's rule into a PPO-shaped network on the stiffness track, scored on the
gate's held-out episodes against its best constant. Protocol: NOTES.md, written before the first run.

    python experiments/rule_cloning/clone.py [--tasks VSWrist/Throw-v0 ...]
"""

import argparse
import json
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from torch import nn

import vswrist_gym  # noqa: F401
from vswrist_gym.agents.procs import limit_threads
from vswrist_gym.agents.protocol import HELDOUT_EVAL_SEEDS, reset_seed
from vswrist_gym.tools.benchmark import STIFFNESS_INDEX, track_entry
from vswrist_gym.tools.gate import EPISODES_PER_SEED, paired, result_path, rule_agent

HERE = Path(__file__).resolve().parent
GATE = HERE.parent / "gate"
DATA_SEEDS = range(20_000, 20_200)
EPOCHS, BATCH, LR = 300, 256, 1e-3


class RuleInResidual:
    """The gate's rule (a posture_stiffness action) as the stiffness-track residual action."""

    def __init__(self, env, levels):
        self.agent = rule_agent(tuple(levels))(env)
        residual = env.unwrapped.cfg["residual"]   # the task's defaults under the entry's settings
        self.nominal, self.scale = residual["stiffness_nominal"], residual["stiffness_scale"]

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        s = float(self.agent.predict(obs, episode_start=episode_start)[0][-1])
        a = np.zeros(4, dtype=np.float32)
        a[STIFFNESS_INDEX] = np.clip((s - self.nominal) / self.scale, -1.0, 1.0)
        return a, None


class Clone:
    def __init__(self, net, mean, std):
        self.net, self.mean, self.std = net, mean, std

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        x = torch.as_tensor((np.asarray(obs, dtype=np.float64) - self.mean) / self.std, dtype=torch.float32)
        with torch.no_grad():
            a3 = float(self.net(x[None])[0, 0])
        a = np.zeros(4, dtype=np.float32)
        a[STIFFNESS_INDEX] = np.clip(a3, -1.0, 1.0)
        return a, None


def rollout(env, agent, seed, data=None) -> float:
    obs, _ = env.reset(seed=int(seed))
    total, first = 0.0, True
    while True:
        a, _ = agent.predict(obs, episode_start=np.array([first]))
        first = False
        if data is not None:
            data.append((np.asarray(obs, dtype=np.float64), float(a[STIFFNESS_INDEX])))
        obs, r, term, trunc, _ = env.step(a)
        total += float(r)
        if term or trunc:
            return total


def fit(data):
    x = np.stack([o for o, _ in data])
    y = np.array([[a] for _, a in data])
    mean, std = x.mean(axis=0), x.std(axis=0) + 1e-8
    torch.manual_seed(0)
    net = nn.Sequential(nn.Linear(x.shape[1], 64), nn.Tanh(), nn.Linear(64, 64), nn.Tanh(), nn.Linear(64, 1))
    opt = torch.optim.Adam(net.parameters(), lr=LR)
    xt = torch.as_tensor((x - mean) / std, dtype=torch.float32)
    yt = torch.as_tensor(y, dtype=torch.float32)
    gen = torch.Generator().manual_seed(0)
    for _ in range(EPOCHS):
        perm = torch.randperm(len(xt), generator=gen)
        for i in range(0, len(xt), BATCH):
            idx = perm[i:i + BATCH]
            loss = ((net(xt[idx]) - yt[idx]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    with torch.no_grad():
        mse = float(((net(xt) - yt) ** 2).mean())
    return Clone(net, mean, std), mse


def study(env_id: str) -> dict:
    g = json.loads(result_path(GATE, env_id).read_text())
    best, levels = g["selection"]["best_constant"], g["selection"]["rule_levels"]
    const = g["headroom"]["returns"]["constant"][f"{best:+.1f}"]
    headroom = g["headroom"]["rule_minus_constant"]["mean"]
    kwargs = track_entry(env_id, "ppo", "stiffness", best)[env_id]["env_kwargs"]
    env = gym.make(env_id, **kwargs)
    data: list = []
    for s in DATA_SEEDS:
        rollout(env, RuleInResidual(env, levels), s, data)
    clone, mse = fit(data)
    resets = [reset_seed(s, i) for s in HELDOUT_EVAL_SEEDS for i in range(EPISODES_PER_SEED)]
    rule = [rollout(env, RuleInResidual(env, levels), r) for r in resets]
    cloned = [rollout(env, clone, r) for r in resets]
    env.close()
    out = {"env_id": env_id, "env_kwargs": kwargs, "samples": len(data), "train_mse": mse,
           "action_var": float(np.var([a for _, a in data])), "gate_headroom": headroom,
           "rule_returns": rule, "clone_returns": cloned,
           "rule_vs_gate_rule": paired(rule, g["headroom"]["returns"]["rule"]),
           "rule_vs_constant": paired(rule, const), "clone_vs_constant": paired(cloned, const)}
    out["clone_share"] = out["clone_vs_constant"]["mean"] / headroom
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", nargs="+", default=["VSWrist/Throw-v0", "VSWrist/Impact-v0", "VSWrist/Insertion-v0"])
    args = ap.parse_args(argv)
    limit_threads(1)
    path = HERE / "results.json"
    doc = json.loads(path.read_text()) if path.is_file() else {}
    for env_id in args.tasks:
        if env_id not in doc:
            doc[env_id] = study(env_id)
            path.write_text(json.dumps(doc, indent=1))
    print("| task | samples | train MSE / action variance | rule (as action) - gate's rule | rule - constant (s.e.) "
          "| clone - constant (s.e.) | clone's share of the headroom |\n|---|---|---|---|---|---|---|")
    for env_id, r in doc.items():
        rv, rc, cc = r["rule_vs_gate_rule"], r["rule_vs_constant"], r["clone_vs_constant"]
        print(f"| `{env_id}` | {r['samples']} | {r['train_mse']:.4f} / {r['action_var']:.4f} | {rv['mean']:+.2f} "
              f"| {rc['mean']:+.2f} ({rc['se']:.2f}) | {cc['mean']:+.2f} ({cc['se']:.2f}) | {r['clone_share']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
