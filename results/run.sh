#!/usr/bin/env bash
# Regenerates the committed results tables (results/<Task>/table.md, summary.json, plots, per-episode CSVs).
# Models and logs go to runs/results/<Task>/ (git-ignored). Run from the repository root; 2 cores assumed.
# Usage: [STEPS=N] [EPISODES=N] [OUT=DIR] bash results/run.sh [TASK ...]      (default: every task, in this order)
#
# Every task: PPO (configs/ppo.yaml), 5 seeds x STEPS steps (default 100,000), two runs at a time (about 7 minutes
# of training per task on 2 cores at 100,000), then PPO and the analytic baseline at five fixed stiffness commands
# evaluated on the same EPISODES episodes per seed (default 20: 100 episodes per agent). Tables go to OUT/<Task>
# (default results). The longer runs of results/README.md:
#   STEPS=400000 EPISODES=50 OUT=results/long bash results/run.sh Drill LoadHold
#   STEPS=400000 EPISODES=200 OUT=results/long200 bash results/run.sh Impact LoadHold
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(Polish Drill Insertion Impact LoadHold)
steps="${STEPS:-100000}"
episodes="${EPISODES:-20}"
out="${OUT:-results}"
for task in "${tasks[@]}"; do
  vswrist compare --task "$task" --algos ppo --seeds 0 1 2 3 4 --episodes "$episodes" --ppo-timesteps "$steps" \
    --out "$out/$task" --runs-dir "runs/$out/$task" --retrain --no-progress
done
