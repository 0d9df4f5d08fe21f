"""Throw-and-stop, first numbers: Throw-v0's throw with the follow-through ending at fe_end (rad) and the episode
lengthened; per agent the release ratio (x rigid bound), the FE overshoot past fe_end after the release and the RMS
FE error from 0.1 to 0.4 s after it. Probe episodes 1000-... only.
Usage: quick.py FE_END N"""
import sys, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.probe import constant_policy, adaptive_policy, within, trim_policy
fe_end, N = float(sys.argv[1]), int(sys.argv[2])
task = {"fe_end": fe_end}
def run(fac, cfg):
    env = gym.make("VSWrist/Throw-v0", config={"episode_s": 1.0, **cfg, "task": task}); u = env.unwrapped
    out = []
    for i in range(N):
        pol = fac(env); o, _ = env.reset(seed=1000 + i); fe, t = [], []
        while True:
            o, r, te, tr, info = env.step(pol(o)); fe.append(float(o[u.obs_slices["posture"]][1])); t.append(u._t)
            if te or tr: break
        fe, t = np.array(fe), np.array(t); rt = info["release_time"]
        after = t > rt; win = (t > rt + 0.1) & (t < rt + 0.4)
        out.append((info["release_speed"] / info["rigid_speed"], fe[after].max() - fe_end, np.sqrt(np.mean((fe[win] - fe_end) ** 2))))
    return np.array(out).mean(0)
res = {"action_mode": "residual", "residual": {"posture_scale": 0.15, "stiffness_scale": 0.0}}
agents = [(f"s={s:+.1f}", lambda e, s=s: constant_policy(e, s), {}) for s in (-1, -0.5, 0, 0.5, 1)]
agents += [("rule(-1,+1)", adaptive_policy, {}), ("rule(-1,+0.5)", lambda e: within(adaptive_policy(e), (-1, 0.5)), {})]
for s0 in (0.0, 0.5):
    for lv in ((0, 0, -1), (0, -1, -1), (1, 0, -1), (-1, -1, -1)):
        agents.append((f"s={s0:+.1f} trim {lv}", lambda e, lv=lv: trim_policy(e, lv), {**res, "residual": {**res["residual"], "stiffness_nominal": s0}}))
for name, fac, cfg in agents:
    r, ov, rms = run(fac, cfg)
    print(f"{name:24s} ratio {r:.2f}  overshoot {ov:+.3f} rad  rms(0.1-0.4 s) {rms:.3f} rad", flush=True)
