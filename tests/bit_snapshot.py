"""Bit-level snapshot of single-env and batch trajectories, to show that a change leaves every number as it was
(on one machine): ``python results/bit_snapshot.py save before.npz`` on the old code, then ``... check
before.npz`` on the new; prints IDENTICAL or the largest difference per trajectory. Every task of
``vswrist_gym.LATEST``: the single env with seeds 0 and 1 and a batch of 8 worlds (one thread), 130 steps of
random actions each, short episodes (0.6 s; Hammer 0.3 s) so that resets happen; observations and rewards."""
import sys, numpy as np, gymnasium as gym, vswrist_gym
from vswrist_gym import LATEST
out = {}
for task, eid in LATEST.items():
    for seed in (0, 1):
        env = gym.make(eid, config={"episode_s": 0.6 if task != "Hammer" else 0.3})
        rng = np.random.default_rng(seed)
        o, _ = env.reset(seed=seed)
        rows = [o.astype(np.float64)]
        for t in range(130):
            o, r, te, tr, info = env.step(rng.uniform(-1, 1, env.action_space.shape))
            rows.append(np.concatenate([o, [r]]))
            if te or tr:
                o, _ = env.reset()
                rows.append(o.astype(np.float64))
        out[f"{task}/{seed}/single"] = np.concatenate(rows)
        env.close()
    venv = gym.make_vec(eid, num_envs=8, vectorization_mode="vector_entry_point", threads=1,
                        config={"episode_s": 0.6 if task != "Hammer" else 0.3})
    rng = np.random.default_rng(5)
    o, _ = venv.reset(seed=3)
    rows = [o.ravel()]
    for t in range(130):
        o, r, te, tr, info = venv.step(rng.uniform(-1, 1, venv.action_space.shape))
        rows += [o.ravel(), r]
    out[f"{task}/batch"] = np.concatenate(rows)
    venv.close()
if sys.argv[1] == "save":
    np.savez(sys.argv[2], **out)
else:
    ref = np.load(sys.argv[2])
    for k, v in out.items():
        w = ref[k]
        same = v.shape == w.shape and np.array_equal(v, w)
        print(k, "IDENTICAL" if same else f"DIFF max {np.max(np.abs(v - w)) if v.shape == w.shape else 'shape'}")
