#!/usr/bin/env bash
# The CartPole · PRED bfloat16 cell with today's learner code ("new", 6932513: the GPU conv forms,
# the ELUs' and batch norms' written-out gradients, the loops as CUDA graphs) against the code of
# the committed fig2_bf16_act cell ("old", f47d63b), side by side in one run, seeds 6-11 each, on
# one 2×H200 host (jax 0.11.2, 2026-11-30). Four processes at once: on each GPU one old and one new
# process of three seeds (6-8 on GPU 0, 9-11 on GPU 1), from frozen trees of the two commits:
#   git archive f47d63b jaml benchmarks envs_mjx assets | tar -x -C .cell/old
#   git archive 6932513 jaml benchmarks envs_mjx assets | tar -x -C .cell/new
# In the first call (LIMIT=500) the new runs finished (498 s) and the old ones stopped at epoch
# 874, checkpointed; a second call on the same machine resumed them to epoch 1000. Only
# config.json, history.jsonl and summary.json of each run are kept.
#   bash docs/results/fig2_pred_ab/job.sh OUT
set -u
out=${1:-runs/fig2_pred_ab}
root=$PWD
export PYTHONUNBUFFERED=1
for side in old new; do
  for gpu in 0 1; do
    if [ "$gpu" = 0 ]; then seeds="6 7 8"; else seeds="9 10 11"; fi
    # shellcheck disable=SC2086  # the seeds are three words
    (cd ".cell/$side" && CUDA_VISIBLE_DEVICES=$gpu XLA_PYTHON_CLIENT_MEM_FRACTION=0.45 \
      PYTHONPATH=$PWD timeout 560 python -m jaml.experiments.fig2 --out "$root/$out/$side" \
      --envs CartPole --variants PRED --seeds $seeds \
      --learner-opt compute_dtype=bfloat16 --learner-opt activation_dtype=bfloat16 \
      --learner-opt current_action=hidden --checkpoint-every 1000 --no-final-checkpoint \
      --time-limit "${LIMIT:-500}") &
  done
done
wait
# Then, here: python -m jaml.experiments.fig2 --out docs/results/fig2_pred_ab/new --report-only \
#   --compare-with docs/results/fig2_pred_ab/old   (and --report-only on old for its own report)
