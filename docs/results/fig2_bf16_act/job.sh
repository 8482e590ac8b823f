#!/usr/bin/env bash
# The bfloat16 Fig. 2 cells of issue #48 on one 4-GPU host, as they were run (compare.md):
# CartPole PRED, DSA and VAE_rpl, 6 seeds each at the paper's settings, with both bf16 knobs
# (compute_dtype and activation_dtype) and the committed fp32 cells' hidden current action.
# Each cell runs as two processes of three seeds, one per GPU. Every process trains until
# LIMIT seconds and checkpoints; the same command again resumes each run from it.
#   bash docs/results/fig2_bf16_act/job.sh OUT LIMIT_SECONDS
set -u
out=${1:-runs/fig2_bf16_act}; limit=${2:-480}
mkdir -p "$out/logs"
export PYTHONUNBUFFERED=1
lane() {  # lane GPU VARIANT SEEDS...
  local gpu=$1 variant=$2; shift 2
  CUDA_VISIBLE_DEVICES=$gpu python -m jaml.experiments.fig2 --out "$out" --envs CartPole \
    --variants "$variant" --seeds "$@" --learner-opt compute_dtype=bfloat16 \
    --learner-opt activation_dtype=bfloat16 --learner-opt current_action=hidden \
    --checkpoint-every 1000 --no-final-checkpoint --time-limit "$limit" \
    >>"$out/logs/${variant}_$1.log" 2>&1 &
}
lane 0 PRED 0 1 2
lane 1 PRED 3 4 5
lane 0 VAE_rpl 0 1 2  # a finished run's lane ends at once
lane 1 VAE_rpl 3 4 5
lane 2 DSA 0 1 2
lane 3 DSA 3 4 5
wait
