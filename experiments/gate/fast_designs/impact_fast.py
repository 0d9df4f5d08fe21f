"""Per-episode look at Impact with fast moves: where do a constant and the wall-aware oracle differ? Probe seeds."""
import sys, json, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.probe import constant_policy, oracle_policy, adaptive_policy
move = json.loads(sys.argv[1]) if len(sys.argv) > 1 else [0.3, 0.4]
extra = json.loads(sys.argv[2]) if len(sys.argv) > 2 else {}
cfg = dict(extra)
cfg.setdefault("task", {})["move_s"] = move
N = int(sys.argv[3]) if len(sys.argv) > 3 else 20
def run(fac, seed):
    env = gym.make("VSWrist/Impact-v1", config=cfg); u = env.unwrapped
    pol = fac(env); o, _ = env.reset(seed=seed); R = 0.0; terms = {}
    while True:
        o, r, te, tr, info = env.step(pol(o)); R += r
        for k, v in info.get("reward_terms", {}).items(): terms[k] = terms.get(k, 0) + v
        if te or tr: break
    return R, bool(u._obstacle), float(info.get("peak_contact_force", np.nan)), info.get("is_success"), terms
agents = {f"s{s:+.1f}": (lambda s: (lambda env: constant_policy(env, s)))(s) for s in (-1, -0.5, 0, 0.5, 1)}
agents["rule"] = adaptive_policy; agents["oracle"] = oracle_policy
res = {k: [run(f, 1000 + i) for i in range(N)] for k, f in agents.items()}
R = {k: np.array([x[0] for x in v]) for k, v in res.items()}
obs_ = np.array([x[1] for x in res["s-1.0"]])
best = max((k for k in R if k.startswith("s")), key=lambda k: R[k].mean())
print("move", move, extra, "best", best, {k: round(R[k].mean(), 1) for k in R})
for k in ("rule", "oracle"):
    d = R[k] - R[best]
    print(f"{k}: {d.mean():+.1f} (se {d.std(ddof=1)/np.sqrt(N):.1f}); obstacle eps {d[obs_].mean():+.1f}, free eps {d[~obs_].mean():+.1f}")
print("success", {k: np.mean([bool(x[3]) for x in v]) for k, v in res.items()})
print("peak force", {k: round(np.nanmean([x[2] for x, o in zip(v, obs_) if o]), 1) for k, v in res.items()})
print("terms", {k: {t: round(np.mean([x[4].get(t, 0) for x in v]), 1) for t in v[0][4]} for k, v in res.items()})
