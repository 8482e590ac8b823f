#!/usr/bin/env bash
# The CartPole · DSA bfloat16 cell with today's learner code ("new", edf9e9f: jaml's recurrent
# layers, the inputs' projection before the scan and the scan unrolled up to 8 steps, with the
# ELUs' and batch norms' written-out gradients) against the code before any of them ("old",
# 428bbaf: Flax's LSTM cells, autodiff's ELU and batch norm), side by side in one run, seeds 6-11
# each, on one 2×H200 host (jax 0.11.2, 2026-11-30). Four processes at once: on each GPU one old
# and one new process of three seeds (6-8 on GPU 0, 9-11 on GPU 1), from frozen trees:
#   git archive 428bbaf jaml benchmarks envs_mjx assets | tar -x -C .cell/old
#   git archive edf9e9f jaml benchmarks envs_mjx assets | tar -x -C .cell/new
# Three calls on one machine (LIMIT=500, 500, 400): the first stopped old at epoch 378 and new at
# 578, the second finished new and stopped old at 874, the third finished old. Only
# config.json, history.jsonl and summary.json of each run are kept.
#   bash docs/results/fig2_dsa_ab/job.sh OUT      (then again, to resume, until all finish)
set -u
# The batch norm's side-by-side job, with DSA for its cell and the trees above in .cell/.
VARIANT=DSA LIMIT=${LIMIT:-500} bash "$(dirname "$0")/../fig2_bn_ab/job.sh" "${1:-runs/fig2_dsa_ab}"
# Then, here: python -m jaml.experiments.fig2 --out docs/results/fig2_dsa_ab/new --report-only \
#   --compare-with docs/results/fig2_dsa_ab/old   (and --report-only on old for its own report)
