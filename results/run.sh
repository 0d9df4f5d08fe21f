#!/usr/bin/env bash
# Regenerates the committed results tables (results/<Task>/table.md, summary.json, plots, per-episode CSVs).
# Models and logs go to runs/results/<Task>/ (git-ignored). Run from the repository root; 2 cores assumed.
# Usage: bash results/run.sh [TASK ...]      (default: every task, in this order)
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(LoadHold Polish Drill Impact Insertion)
for task in "${tasks[@]}"; do
  case "$task" in
    LoadHold)  # the README's main job: default budgets (configs/ppo.yaml, configs/sac.yaml), 3 seeds
      vswrist compare --task LoadHold --out results/LoadHold --runs-dir runs/results/LoadHold --no-progress ;;
    *)         # PPO only, 5 seeds, 40,000 steps per seed, 5 evaluation episodes per seed
      vswrist compare --task "$task" --algos ppo --seeds 0 1 2 3 4 --episodes 5 --ppo-timesteps 40000 \
        --out "results/$task" --runs-dir "runs/results/$task" --no-progress ;;
  esac
done
