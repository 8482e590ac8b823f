#!/usr/bin/env bash
# The Fig. 9 run of docs/results/fig9_runs/reference_2078 on one 4×H100 hold: PRED and
# PRED+AML_trnsv, seeds 0-5, to learner epoch 2,000 (epoch 2,078), analyses every 400 learner
# epochs. The lane layout is the same in every call (three seeds stacked per process, one
# process per GPU), so a seed's PPO stream is bit-identical in both methods from the first epoch
# to the last: the stream's bits depend on how many runs are stacked with it (fig9.md). Each
# process stops by its --time-limit with a checkpoint; the next call resumes. Other methods
# (the controls, AML_syz) run in the same lanes get the same streams, bit for bit, so they pair
# with the committed PRED records (the report's stream check says whether they did).
#   bash docs/results/fig9_runs/reference_2078/job.sh LIMIT HARD_LIMIT [OUT [METHOD_A METHOD_B [DYNAMICS]]]
# DYNAMICS: drawn (default, the runs committed here) or fixed, with relations fitted on the CPU
# by `jaml fig9 --recipe reference --dynamics fixed --pilot-only --out runs/fig9ref_fixed`.
set -u
limit=$1; hard=$2; out=${3:-runs/fig9_2078}; a=${4:-PRED}; b=${5:-PRED+AML_trnsv}; dyn=${6:-drawn}
mkdir -p "$out/logs"
# The relations were fitted once on a CPU (`jaml fig9 --pilot-only`) and travel with the job.
rel=runs/fig9ref/relations; [ "$dyn" = drawn ] || rel=runs/fig9ref_$dyn/relations
[ -d "$out/relations" ] || cp -r "$rel" "$out/relations"
export XLA_FLAGS="--xla_gpu_deterministic_ops=true" PYTHONUNBUFFERED=1
export JAX_COMPILATION_CACHE_DIR=$PWD/runs/jax_cache XLA_PYTHON_CLIENT_MEM_FRACTION=0.9
lane() {  # lane GPU METHOD "SEEDS"
  CUDA_VISIBLE_DEVICES=$1 timeout "$hard" python -m jaml.experiments.fig9 --out "$out" \
    --recipe reference --dynamics "$dyn" --methods "$2" --seeds $3 --eval-every 400 --checkpoint-every 400 \
    --time-limit "$limit" >>"$out/logs/$2.seeds${3// /}.log" 2>&1
}
lane 0 "$a" "0 1 2" & lane 1 "$b" "0 1 2" &
lane 2 "$a" "3 4 5" & lane 3 "$b" "3 4 5" &
wait
for f in "$out"/*/seed_*/summary.json; do
  python -c "import json,sys; s=json.load(open(sys.argv[1])); print(sys.argv[1], s['status'], s['epoch'], s['checkpoint_epoch'], round(s['seconds_this_call']), {k: round(v) for k, v in s['seconds_by_phase'].items()})" "$f"
done
