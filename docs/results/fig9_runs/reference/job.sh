#!/usr/bin/env bash
# The reference-recipe Fig. 9 job on one 4-GPU host, as it was run (docs/results/fig9.md):
# two methods per GPU, six seeds each (one program per method, the seeds stacked), and the
# Fig. 2 CartPole PRED cell with the observed current action on the fourth GPU. Every process
# stops after LIMIT seconds; a later call resumes each run from its last checkpoint.
#   bash docs/results/fig9_runs/reference/job.sh OUT LIMIT_SECONDS [STOP_AFTER_EPOCHS]
set -u
out=${1:-runs/fig9ref}; limit=${2:-540}; stop=${3:-}
mkdir -p "$out/logs"
# A seed's stream must be the same for every method (the comparison is paired): XLA's
# deterministic GPU kernels, so that no reduction depends on the order its threads finish.
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
extra=(); [ -n "$stop" ] && extra=(--stop-after "$stop")
lane() {  # lane GPU LOG COMMAND...
  local gpu=$1 log=$2; shift 2
  CUDA_VISIBLE_DEVICES=$gpu timeout "$limit" "$@" >"$out/logs/$log.log" 2>&1 &
}
fig9=(python -m jaml.experiments.fig9 --out "$out" --recipe reference "${extra[@]}")
lane 0 PRED "${fig9[@]}" --methods PRED
lane 0 AML_trnsv "${fig9[@]}" --methods PRED+AML_trnsv
lane 1 AML_syz "${fig9[@]}" --methods PRED+AML_syz
lane 1 ok_rows "${fig9[@]}" --methods PRED+ok_rows
lane 2 random_rows "${fig9[@]}" --methods PRED+random_rows
lane 2 VAE_rpl "${fig9[@]}" --methods VAE_rpl
lane 3 random_rows_5pct "${fig9[@]}" --methods PRED+random_rows_5pct  # added after 2026-11-27
lane 3 fig2_PRED_observed python -m jaml.experiments.fig2 --out "$out/fig2_observed" \
  --envs CartPole --variants PRED --learner-opt current_action=observed "${extra[@]}"
wait
