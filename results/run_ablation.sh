#!/usr/bin/env bash
# Ablation: does the learned policy gain from adapting the STIFFNESS, or only from trimming the posture?
# The same PPO runs as results/run.sh (same hyperparameters, seeds, budget, evaluation episodes), with the
# residual's stiffness_scale set to 0: the stiffness stays at the task's best constant command and the policy
# only moves the posture reference. The config is derived from configs/ppo.yaml at run time (one source).
# Writes results/ablation/<Task>/; models and logs in runs/ablation/<Task>/ (git-ignored).
# Usage: bash results/run_ablation.sh [TASK ...]
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(Polish Drill Insertion Impact LoadHold)
mkdir -p runs/ablation
cfg=runs/ablation/ppo_posture_only.yaml
sed 's/stiffness_scale: [0-9.]*/stiffness_scale: 0.0/' vswrist_gym/configs/ppo.yaml > "$cfg"
for task in "${tasks[@]}"; do
  vswrist compare --task "$task" --algos ppo --seeds 0 1 2 3 4 --episodes 20 --ppo-timesteps 100000 \
    --ppo-config "$cfg" --out "results/ablation/$task" --runs-dir "runs/ablation/$task" --retrain --no-progress
done
