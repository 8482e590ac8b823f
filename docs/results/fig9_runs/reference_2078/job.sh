#!/usr/bin/env bash
# The 2,000-learner-epoch Fig. 9 job on one 4-GPU host: PRED, PRED+AML_trnsv and the 5 %
# random-row control, seeds 0-3, one GPU per seed and one process per (seed, method), so the
# three methods of a seed see the same stream on the same card. Each process trains until
# LIMIT seconds after its start, checkpoints and stops; the next call of the same hold resumes
# every run (compiled programs come from the persistent cache the first call filled).
#   bash docs/results/fig9_runs/reference_2078/job.sh OUT LIMIT
set -u
out=${1:-runs/fig9long}; limit=${2:-480}
mkdir -p "$out/logs"
# The relations were fitted once on a CPU (`jaml fig9 --pilot-only`) and travel with the job.
[ -d "$out/relations" ] || cp -r runs/fig9ref/relations "$out/relations"
# A seed's stream must be the same for every method (the comparison is paired).
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3 JAX_COMPILATION_CACHE_DIR=$PWD/runs/jax_cache
gpus=$(nvidia-smi -L | wc -l)
for seed in 0 1 2 3; do
  for method in PRED PRED+AML_trnsv PRED+random_rows_5pct; do
    CUDA_VISIBLE_DEVICES=$((seed % gpus)) timeout $((limit + 90)) python -m jaml.experiments.fig9 \
      --out "$out" --recipe reference --methods "$method" --seeds "$seed" --eval-every 400 \
      --checkpoint-every 400 --time-limit "$limit" >>"$out/logs/$method.$seed.log" 2>&1 &
  done
done
wait
date
for f in "$out"/*/seed_*/summary.json; do
  python -c "import json,sys; s=json.load(open(sys.argv[1])); print(sys.argv[1], s['status'], s['epoch'], s['checkpoint_epoch'], {k: round(v) for k, v in s['seconds_by_phase'].items()})" "$f"
done
