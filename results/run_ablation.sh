#!/usr/bin/env bash
# Ablations: does the learned policy gain from adapting the STIFFNESS, or only from trimming the posture?
# The same PPO runs as results/run.sh (same hyperparameters, seeds, budget, evaluation episodes), with one of the
# residual's two channels switched off (the config is derived from configs/ppo.yaml at run time: one source):
#   ABLATION=posture_only   (default) residual.stiffness_scale 0: the stiffness stays at the task's best constant
#                           command and the policy only moves the posture reference -> results/ablation/<Task>
#   ABLATION=stiffness_only residual.posture_scale 0: the posture reference is the task's target (as the analytic
#                           baseline's) and the policy only schedules the stiffness -> results/ablation_stiffness/<Task>
# STEPS (default 100,000) and EPISODES (default 20) as in results/run.sh; OUT overrides the output directory.
# Models and logs in runs/<out>/<Task>/ (git-ignored).
# Usage: [ABLATION=posture_only|stiffness_only] [STEPS=N] [EPISODES=N] [OUT=DIR] bash results/run_ablation.sh [TASK ...]
# The longer stiffness-only run of results/README.md:
#   ABLATION=stiffness_only STEPS=400000 EPISODES=50 OUT=results/long_stiffness bash results/run_ablation.sh Polish Insertion Impact
set -euo pipefail
tasks=("$@")
[ ${#tasks[@]} -gt 0 ] || tasks=(Polish Drill Insertion Impact LoadHold)
mode="${ABLATION:-posture_only}"
case "$mode" in
  posture_only) out=ablation; edit='s/stiffness_scale: [0-9.]*/stiffness_scale: 0.0/' ;;
  stiffness_only) out=ablation_stiffness; edit='s/posture_scale: [0-9.]*/posture_scale: 0.0/' ;;
  *) echo "ABLATION must be posture_only or stiffness_only, got '$mode'" >&2; exit 2 ;;
esac
out="${OUT:-results/$out}"
steps="${STEPS:-100000}"
episodes="${EPISODES:-20}"
mkdir -p "runs/$out"
cfg="runs/$out/ppo_$mode.yaml"
sed "$edit" vswrist_gym/configs/ppo.yaml > "$cfg"
cmp -s "$cfg" vswrist_gym/configs/ppo.yaml && { echo "the $mode edit changed nothing in ppo.yaml" >&2; exit 1; }
for task in "${tasks[@]}"; do
  vswrist compare --task "$task" --algos ppo --seeds 0 1 2 3 4 --episodes "$episodes" --ppo-timesteps "$steps" \
    --ppo-config "$cfg" --out "$out/$task" --runs-dir "runs/$out/$task" --retrain --no-progress
done
