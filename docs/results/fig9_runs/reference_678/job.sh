#!/usr/bin/env bash
# The long Fig. 9 job on one 4-GPU host: PRED, AML_trnsv and the two ok-row controls to 2,000
# learner epochs, each method as two three-seed lanes, two lanes per GPU. Every process stops
# after LIMIT seconds (or STOP_AFTER epochs); the next call of the same hold resumes each run
# from its last checkpoint (one every CHECKPOINT_EVERY epochs).
#   bash docs/results/fig9_runs/reference_678/job.sh OUT LIMIT [STOP_AFTER] [CHECKPOINT_EVERY]
set -u
out=${1:-runs/fig9ref}; limit=${2:-540}; stop=${3:-}; every=${4:-100}
mkdir -p "$out/logs"
# A seed's stream must be the same for every method (the comparison is paired).
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.45
extra=(--checkpoint-every "$every"); [ -n "$stop" ] && extra+=(--stop-after "$stop")
# The relations first, once (instant when OUT/relations holds the finished sets): the lanes
# then only read them.
python -m jaml.experiments.fig9 --out "$out" --recipe reference --pilot-only \
  >"$out/logs/relations.log" 2>&1
lane=0
for method in PRED PRED+AML_trnsv PRED+ok_rows PRED+random_rows_5pct; do
  for seeds in "0 1 2" "3 4 5"; do
    # shellcheck disable=SC2086
    CUDA_VISIBLE_DEVICES=$((lane / 2)) timeout "$limit" python -m jaml.experiments.fig9 \
      --out "$out" --recipe reference --methods "$method" --seeds $seeds "${extra[@]}" \
      >"$out/logs/$method.${seeds// /}.log" 2>&1 &
    lane=$((lane + 1))
  done
done
wait
date
for f in "$out"/*/seed_*/metrics.jsonl; do
  echo "$f $(tail -n 1 "$f" | cut -c1-14)"
done
