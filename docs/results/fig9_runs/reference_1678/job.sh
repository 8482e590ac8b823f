#!/usr/bin/env bash
# The Fig. 9 run of docs/results/fig9_runs/reference_1678, as its three calls of one 4×H100
# hold ran it: PRED, PRED+AML_trnsv and the 5 % random-row control, seeds 0-3, analyses every
# 400 learner epochs, every process stopping by its --time-limit with a checkpoint, the next
# call resuming. The lane layout changed between calls (the first was slow), and a seed's PPO
# stream is bit-identical only while its runs are stacked the same way (see fig9.md).
#   bash docs/results/fig9_runs/reference_1678/job.sh CALL [OUT]
set -u
call=$1; out=${2:-runs/fig9long}
mkdir -p "$out/logs"
# The relations were fitted once on a CPU (`jaml fig9 --pilot-only`) and travel with the job.
[ -d "$out/relations" ] || cp -r runs/fig9ref/relations "$out/relations"
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=$PWD/runs/jax_cache
lane() {  # lane GPU METHOD "SEEDS" LIMIT HARD_LIMIT
  CUDA_VISIBLE_DEVICES=$1 timeout "$5" python -m jaml.experiments.fig9 --out "$out" \
    --recipe reference --methods "$2" --seeds $3 --eval-every 400 --checkpoint-every 400 \
    --time-limit "$4" >>"$out/logs/$2.call$call.log" 2>&1
}
case $call in
  1)  # one process per (seed, method), a GPU per seed: ~1.1 epochs/s a process
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.3
    for seed in 0 1 2 3; do
      for method in PRED PRED+AML_trnsv PRED+random_rows_5pct; do
        lane "$seed" "$method" "$seed" 470 560 &
      done
    done ;;
  2)  # one 4-seed lane per method on GPUs 0-2
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.9
    lane 0 PRED "0 1 2 3" 520 575 & lane 1 PRED+AML_trnsv "0 1 2 3" 520 575 &
    lane 2 PRED+random_rows_5pct "0 1 2 3" 520 575 & ;;
  3)  # the slowest method (AML) as two 2-seed lanes, the others one lane each
    export XLA_PYTHON_CLIENT_MEM_FRACTION=0.9
    lane 0 PRED+AML_trnsv "0 1" 545 565 & lane 1 PRED+AML_trnsv "2 3" 545 565 &
    lane 2 PRED "0 1 2 3" 545 565 & lane 3 PRED+random_rows_5pct "0 1 2 3" 545 565 & ;;
esac
wait
for f in "$out"/*/seed_*/summary.json; do
  python -c "import json,sys; s=json.load(open(sys.argv[1])); print(sys.argv[1], s['status'], s['epoch'], s['checkpoint_epoch'], {k: round(v) for k, v in s['seconds_by_phase'].items()})" "$f"
done
