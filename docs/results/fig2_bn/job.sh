#!/usr/bin/env bash
# The bfloat16 CartPole · VAE_rpl cell of issue #61 item 4, trained at f1ae7b5 (jaml's BatchNorm
# with its backward written out, 9f191fd, and the ELU's gradient from its output, d6bfcc2) as it
# was run (compare.md): one H200 (jax 0.11.2, 2026-11-30), two calls one after the other on the
# same machine, each one process of three seeds, from a frozen tree of the commit:
#   git archive f1ae7b5 jaml benchmarks envs_mjx assets | tar -x -C .cell
# Call 1 trained 309 s (320.6 s wall, compilation included), call 2 233 s (240.8 s wall); both
# reached epoch 1000. Only config.json, history.jsonl and summary.json of each run are kept.
#   bash docs/results/fig2_bn/job.sh OUT
set -u
out=${1:-runs/fig2_bn}
export PYTHONUNBUFFERED=1
for seeds in "0 1 2" "3 4 5"; do
  # shellcheck disable=SC2086  # the seeds are three words
  timeout 570 python -m jaml.experiments.fig2 --out "$out" --envs CartPole --variants VAE_rpl \
    --seeds $seeds --learner-opt compute_dtype=bfloat16 --learner-opt activation_dtype=bfloat16 \
    --learner-opt current_action=hidden --checkpoint-every 1000 --no-final-checkpoint
done
# Then, here: python -m jaml.experiments.fig2 --out docs/results/fig2_bn --report-only \
#   --compare-with docs/results/fig2_forms
