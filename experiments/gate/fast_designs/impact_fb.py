"""Fast Impact design: the gate's posture feedback (IntegralTrim) at the best constant, paired against it. Probe seeds."""
import sys, json, numpy as np, gymnasium as gym
import vswrist_gym
from vswrist_gym.tools.gate import IntegralTrim, feedback_kwargs
from vswrist_gym.tools.probe import constant_policy
extra = json.loads(sys.argv[1]); s0 = float(sys.argv[2]); N = int(sys.argv[3])
def ret(make_agent, cfg, seed, sb3=False):
    env = gym.make("VSWrist/Impact-v1", config=cfg); ag = make_agent(env); o, _ = env.reset(seed=seed); R = 0.0; first = True
    while True:
        a = ag.predict(o, episode_start=np.array([first]))[0] if sb3 else ag(o); first = False
        o, r, te, tr, _ = env.step(a); R += r
        if te or tr: return R
base = [ret(lambda env: constant_policy(env, s0), extra, 1000 + i) for i in range(N)]
kw = feedback_kwargs(s0)["config"]; cfg = {**extra, **kw}
for k in (0, 2, 5, 10, 20):
    r = [ret(lambda env: IntegralTrim(env, k), cfg, 1000 + i, sb3=True) for i in range(N)]
    d = np.array(r) - np.array(base)
    print(f"k={k:2d}: {d.mean():+.1f} (se {d.std(ddof=1)/np.sqrt(N):.1f})", flush=True)
