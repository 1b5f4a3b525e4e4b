#!/usr/bin/env bash
# Issue 31: one FastSAC Go1 learner call (bf16, recipe) alone and beside 15 busy CPU processes (the in-run load of the
# 15 rollout workers), as a loop (default), unrolled (--config unroll_updates=true) and with XLA's command buffers
# taking the loop (WHILE). Results under $OUT. (unroll_updates existed at commit 2f935f3 only: measured no gain, removed.)
set -u
OUT=${OUT:-/tmp/p31_inrun}; mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
base="--xla_gpu_enable_triton_gemm=false"
cb="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL"
lu() {  # name, xla flags, extra args
  XLA_FLAGS="$2" python3 bench/learner_update.py --platforms jax --dtypes bfloat16 --repeats 20 --algos fastsac \
    --recipe experiments/fastsac_go1.py --sizes go1 --out "$OUT/lu_$1.json" ${3:-} 2>&1 | grep "grad steps" | sed "s/^/$1: /"
}
for load in idle busy; do
  pids=""
  if [ $load = busy ]; then for i in $(seq 15); do (while :; do :; done) & pids="$pids $!"; done; fi
  lu loop_$load "$base"
  lu unrolled_$load "$base" "--config unroll_updates=true"
  lu cmdbuf_$load "$base $cb"
  [ -n "$pids" ] && kill $pids
done
