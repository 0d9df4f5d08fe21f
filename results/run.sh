#!/usr/bin/env bash
# Regenerates the committed results tables (results/<Task>/table.md, summary.json, plots, per-episode CSVs).
# Models and logs go to runs/results/<Task>/ (git-ignored). Run from the repository root; 2 cores assumed.
# Usage: bash results/run.sh [TASK ...]      (default: every task, in this order)
#
# Every task: PPO (configs/ppo.yaml), 5 seeds x 100,000 steps, two runs at a time (about 13 minutes of training
# per task on 2 cores), then PPO and the analytic baseline at five fixed stiffness commands evaluated on the same
# 20 episodes per seed (100 episodes per agent).
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(Polish Drill Insertion Impact LoadHold)
for task in "${tasks[@]}"; do
  vswrist compare --task "$task" --algos ppo --seeds 0 1 2 3 4 --episodes 20 --ppo-timesteps 100000 \
    --out "results/$task" --runs-dir "runs/results/$task" --retrain --no-progress
done
