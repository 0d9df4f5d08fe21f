"""Target-speed throw, necessity: one posture-only PPO per training seed (Throw-v0's packaged configs/ppo.yaml entry
as the gate builds it: residual mode, posture_scale 0.15, stiffness_scale 0, the stiffness held at S0), trained on
the probe id, scored paired against the constant and the target rule on probe episodes 1000..1000+N-1.
Usage: ppo.py LO HI TOL S0 STEPS SEEDS(comma) N [stiffness]   (runs under runs/target_throw/, git-ignored)
With ``stiffness``: the stiffness track instead (Throw-v0's packaged entry unchanged: posture_scale 0,
stiffness_scale 2 about S0), to see whether the learner finds the target rule at this budget."""
import os, sys, yaml, numpy as np, gymnasium as gym
from pathlib import Path
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import vswrist_gym
from target_env import register_probe
from vswrist_gym.tools.gate import posture_only_entry
from vswrist_gym.agents.train import train
from vswrist_gym.agents.evaluate import AgentSpec
lo, hi, tol, s0, steps = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
seeds, N = [int(x) for x in sys.argv[6].split(",")], int(sys.argv[7])
track = sys.argv[8] if len(sys.argv) > 8 else "posture"
EID = register_probe({"target_ratio": [lo, hi], "target_tolerance": tol})
import measure_lib as M
root = Path(__file__).resolve().parents[3] / "runs" / "target_throw" / f"{lo}-{hi}-{tol}-s{s0:+.1f}-{steps}-{track}"
PROBE = [1000 + i for i in range(N)]
base = M.returns(EID, lambda e, t: M.constant_policy(e, s0), PROBE)
H, se = M.paired(M.returns(EID, M.rule_factory(lo, hi, tol), PROBE), base)
print(f"targets U[{lo}, {hi}], tent {tol}, s0 {s0:+.1f}, {steps} steps; rule - constant {H:+.2f} (se {se:.2f})", flush=True)
for seed in seeds:
    entry = posture_only_entry("VSWrist/Throw-v0", s0, steps)
    entry = {EID: entry["VSWrist/Throw-v0"], "vswrist": {EID: entry["vswrist"]["VSWrist/Throw-v0"]}}
    if track == "stiffness":
        entry[EID]["env_kwargs"]["residual"] = {"posture_scale": 0.0, "stiffness_scale": 2.0, "stiffness_nominal": s0}
    run = root / f"seed{seed}"; run.parent.mkdir(parents=True, exist_ok=True)
    cfgp = run.parent / "entry.yaml"; cfgp.write_text(yaml.safe_dump(entry, sort_keys=False))
    if not (run / "model.zip").is_file():
        train(EID, "ppo", run, config=cfgp, timesteps=steps, seed=seed, progress=False, log=lambda *a: None)
    spec = AgentSpec(str(run), checkpoint="final")
    r = M.returns(EID, lambda env, t, spec=spec: spec.make(env), PROBE, spec.env_kwargs, sb3=True)
    g, gse = M.paired(r, base)
    print(f"{track}-only PPO seed {seed}: gain {g:+.2f} (se {gse:.2f}), share {g / H:.2f}", flush=True)
