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
#   bash docs/results/fig2_pred_ab/job.sh OUT      (LIMIT=500, then again for the resume)
set -u
# The batch norm's side-by-side job, with PRED for its cell and the trees above in .cell/.
VARIANT=PRED LIMIT=${LIMIT:-500} bash "$(dirname "$0")/../fig2_bn_ab/job.sh" "${1:-runs/fig2_pred_ab}"
# Then, here: python -m jaml.experiments.fig2 --out docs/results/fig2_pred_ab/new --report-only \
#   --compare-with docs/results/fig2_pred_ab/old   (and --report-only on old for its own report)
