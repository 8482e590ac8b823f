#!/usr/bin/env bash
# The next hold's Fig. 9 job (not run yet): PRED, AML_trnsv and the two ok-row controls to
# 2,000 learner epochs on one 4-GPU host, each method as two three-seed lanes, two lanes per GPU.
# Every process stops after LIMIT seconds; the next call of the same hold resumes it.
#   bash docs/results/fig9_runs/reference/job_2000.sh OUT LIMIT_SECONDS
set -u
out=${1:-runs/fig9ref}; limit=${2:-540}
mkdir -p "$out/logs"
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
# The relations first, once (instant when OUT/relations holds the finished sets): the lanes then
# only read them.
python -m jaml.experiments.fig9 --out "$out" --recipe reference --pilot-only >"$out/logs/relations.log" 2>&1
gpu=0
for method in PRED PRED+AML_trnsv PRED+ok_rows PRED+random_rows_5pct; do
  for seeds in "0 1 2" "3 4 5"; do
    # shellcheck disable=SC2086
    CUDA_VISIBLE_DEVICES=$((gpu / 2)) timeout "$limit" python -m jaml.experiments.fig9 \
      --out "$out" --recipe reference --methods "$method" --seeds $seeds \
      >"$out/logs/$method.${seeds// /}.log" 2>&1 &
    gpu=$((gpu + 1))
  done
done
wait
