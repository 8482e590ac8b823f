#!/usr/bin/env bash
# Issue #61 item 4, the batch norm's written-out backward old against new in one run: the
# CartPole · VAE_rpl bfloat16 cell at d6bfcc2 (Flax's BatchNorm, "old") and at 9f191fd (jaml's
# BatchNorm, "new"; the only change between the two), seeds 6-11, on one 2×H200 host (jax 0.11.2,
# 2026-11-30). Four processes at once: on each GPU one old and one new process of three seeds
# (6-8 on GPU 0, 9-11 on GPU 1), from frozen trees of the two commits:
#   git archive d6bfcc2 jaml benchmarks envs_mjx assets | tar -x -C .cell/old
#   git archive 9f191fd jaml benchmarks envs_mjx assets | tar -x -C .cell/new
# The first call stopped every run at its 480 s time limit (epoch 878 or 942, checkpointed); a
# second call on the same machine resumed them to epoch 1000 (about 155 s). Only config.json,
# history.jsonl and summary.json of each run are kept.
#   bash docs/results/fig2_bn_ab/job.sh OUT      (LIMIT=480, then again for the resume)
# VARIANT=PRED or DSA runs that cell instead (docs/results/fig2_pred_ab/job.sh,
# docs/results/fig2_dsa_ab/job.sh).
set -u
out=${1:-runs/fig2_bn_ab}
root=$PWD
export PYTHONUNBUFFERED=1
for side in old new; do
  for gpu in 0 1; do
    if [ "$gpu" = 0 ]; then seeds="6 7 8"; else seeds="9 10 11"; fi
    # shellcheck disable=SC2086  # the seeds are three words
    (cd ".cell/$side" && CUDA_VISIBLE_DEVICES=$gpu XLA_PYTHON_CLIENT_MEM_FRACTION=0.45 \
      PYTHONPATH=$PWD timeout 560 python -m jaml.experiments.fig2 --out "$root/$out/$side" \
      --envs CartPole --variants "${VARIANT:-VAE_rpl}" --seeds $seeds \
      --learner-opt compute_dtype=bfloat16 --learner-opt activation_dtype=bfloat16 \
      --learner-opt current_action=hidden --checkpoint-every 1000 --no-final-checkpoint \
      --time-limit "${LIMIT:-480}") &
  done
done
wait
# Then, here: python -m jaml.experiments.fig2 --out docs/results/fig2_bn_ab/new --report-only \
#   --compare-with docs/results/fig2_bn_ab/old   (and --report-only on old for its own report)
