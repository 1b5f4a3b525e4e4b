#!/usr/bin/env bash
# Issue 31, fused LayerNorm+ReLU: learner_update rows before (the tree in $BEFORE) and after (this checkout), bf16,
# same machine, one call; traces of the "after" rows summarised. Results under $OUT.
set -u
OUT=${OUT:-/tmp/p31_out}; BEFORE=${BEFORE:-.before}
mkdir -p "$OUT" /tmp/p31
export PYTHONUNBUFFERED=1 XLA_FLAGS="--xla_gpu_enable_triton_gemm=false"
nvidia-smi -L; nproc
for side in before after; do
  root=$PWD; [ $side = before ] && root=$PWD/$BEFORE
  for r in "fastsac_go1 fastsac go1" "fastsac_g1 fastsac g1" "flashsac_go2 flashsac go2"; do
    set -- $r
    prof=""; [ $side = after ] && prof="--profile_dir /tmp/p31/prof_$1"
    (cd "$root" && PYTHONPATH=$root python3 bench/learner_update.py --platforms jax --dtypes bfloat16 --repeats 10 \
      --algos $2 --recipe experiments/$1.py --sizes $3 $prof --out "$OUT/lu_${side}_$1.json" ${EXTRA:-}) 2>&1 | grep -v Warning
  done
done
for d in /tmp/p31/prof_*/*/; do
  n=$(basename "$(dirname "$d")"); python3 bench/trace_summary.py "$d" --top 40 --out "$OUT/trace_$n.json" > /tmp/p31/ts.txt
  echo "== $n"; head -14 /tmp/p31/ts.txt
done
