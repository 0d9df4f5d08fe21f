"""Fast Impact design, necessity check: posture-only PPO (stiffness held at the constant) and a stiffness-track PPO,
80,000 steps, Impact-v1's packaged entry; training seeds from 100, probe episodes (reset seeds 1000-1039)."""
import sys, json, copy, yaml, numpy as np, gymnasium as gym
from pathlib import Path
import vswrist_gym
from vswrist_gym.tools.gate import posture_only_entry
from vswrist_gym.agents.train import train
from vswrist_gym.agents.evaluate import AgentSpec
from vswrist_gym.tools.probe import constant_policy, adaptive_policy
task = json.loads(sys.argv[1]); s0 = float(sys.argv[2]); tag = sys.argv[3]; seeds = [int(x) for x in sys.argv[4].split(",")]
N = 40; EID = "VSWrist/Impact-v1"; root = Path(__file__).resolve().parents[3] / "runs" / "fast_designs" / tag
def ret_fn(make_agent, kwargs, seed, sb3):
    env = gym.make(EID, **kwargs); ag = make_agent(env); o, _ = env.reset(seed=seed); R = 0.0; first = True
    while True:
        a = ag.predict(o, episode_start=np.array([first]), deterministic=True)[0] if sb3 else ag(o); first = False
        o, r, te, tr, _ = env.step(a); R += r
        if te or tr: return R
base = np.array([ret_fn(lambda env: constant_policy(env, s0), {"config": {"task": task}}, 1000 + i, False) for i in range(N)])
rule = np.array([ret_fn(adaptive_policy, {"config": {"task": task}}, 1000 + i, False) for i in range(N)])
d = rule - base; print(f"rule - constant {d.mean():+.1f} (se {d.std(ddof=1)/np.sqrt(N):.1f})", flush=True)
for track in ("posture", "stiffness"):
    for seed in seeds:
        entry = posture_only_entry(EID, s0, 80000)
        e = entry[EID]; e["env_kwargs"]["task"] = task
        if track == "stiffness":
            e["env_kwargs"]["residual"] = {"posture_scale": 0.0, "stiffness_scale": 2.0, "stiffness_nominal": s0}
        run = root / track / f"seed{seed}"; run.parent.mkdir(parents=True, exist_ok=True)
        cfgp = run.parent / "entry.yaml"; cfgp.write_text(yaml.safe_dump(entry, sort_keys=False))
        if not (run / "model.zip").is_file():
            train(EID, "ppo", run, config=cfgp, timesteps=80000, seed=seed, progress=False, log=lambda *a: None)
        spec = AgentSpec(str(run), checkpoint="final")
        r = np.array([ret_fn(spec.make, spec.env_kwargs, 1000 + i, True) for i in range(N)])
        g = r - base
        print(f"{track} seed {seed}: {g.mean():+.1f} (se {g.std(ddof=1)/np.sqrt(N):.1f}), share of rule {g.mean()/d.mean():.2f}", flush=True)
