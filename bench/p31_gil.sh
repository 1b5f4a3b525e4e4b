#!/usr/bin/env bash
# Issue 31 on the 1-GPU machine: what the learner process's other Python threads cost the learner thread (the GIL).
# FastSAC Go1 (fastsac_async, SEED) once per variant, MAXS seconds each; per run (bench/learner_runs.py, from 40 s to
# the end): calls/s, gradient steps/s, the learner thread's milliseconds per call (perf/update_s: the update's dispatch;
# perf/fetch_s: its results to the host), and the time to walking if reached.
#   base      as bench/time_to_target.py runs it (13 workers, which --pin_cpus=auto keeps off 3 cores; since 4182490 the
#             LayerNorm kernels "auto": the Pallas ones on one NVIDIA GPU)
#   w15       15 workers, no affinity (--pin_cpus=-1): the base before that
#   noeval    no evaluation during the run (--eval_every past the budget): the evaluator thread's share
#   swi       the interpreter's GIL switch interval 0.5 ms instead of 5 ms (sys.setswitchinterval, via sitecustomize)
#   u16       16 gradient steps per learner call instead of the recipe's 8 (the same update-to-data ratio)
#   nocb      no XLA command buffers (--xla_gpu_enable_command_buffer=): the scan's steps as plain kernel launches
#   wNpK      N workers kept off the first K cores (--pin_cpus=K)
#   noprec    the update compiled at its first call, not while the rings fill (--precompile=off)
#   bsync     threads waiting on the GPU sleep in the driver instead of spinning a core (XLA's CUDA context flag from
#             TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE=blocking_sync; the default, CUDA's "auto", spins while a process
#             has fewer GPU contexts than the machine has cores: each waiting thread holds a core the learner
#             process's other threads, on the 3 cores the workers leave it, then lack)
#   yield     the same with TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE=yield (spin, yielding the core between polls)
#   ln        the critics' LayerNorm + ReLU forward and backward as Pallas kernels (ln_forward=ln_backward=pallas)
#   xla       the same as XLA's programs (ln_forward=ln_backward=xla: the base before 4182490)
#   c:K=V     the recipe's config field K set to V (--config=K=V), e.g. c:batch_size=4096
#   A+B       both parts, e.g. ln+c:utd=0.01171875 (the Pallas kernels and 12 gradient steps per 1024 transitions)
#   f:F=V     the experiment flag --F=V, e.g. f:envs_per_worker=128 (after the configuration's own: it wins)
# Each run starts from an empty compilation cache of its own (time_to_target.py's default), so runs compare like for
# like whatever ran before on the machine. SEEDS (default: SEED) runs every variant for each seed, variants inner.
#   VARIANTS="base w15" SEEDS="0 1 2" MAXS=160 bash bench/p31_gil.sh
set -u
OUT=${OUT:-/tmp/p31_gil}; mkdir -p "$OUT"
ROBOTS="unitree_go1" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -3 "$OUT/setup.txt"
mkdir -p /tmp/swi && echo 'import sys; sys.setswitchinterval(0.0005)' > /tmp/swi/sitecustomize.py
# whether this jax's CUDA plugin reads the schedule variable (bsync / yield change nothing if it does not)
plugin=$(python3 -c 'import os, jax_plugins.xla_cuda12 as p; print(os.path.dirname(p.__file__))' 2>/dev/null)
[ -n "$plugin" ] && echo "CUDA plugin files naming TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE:" \
  "$(grep -l TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE "$plugin"/*.so 2>/dev/null | wc -l)"
for seed in ${SEEDS:-${SEED:-0}}; do
for v in ${VARIANTS:-base noeval swi}; do
  run=$(echo "${v}" | tr ':=+' '___')_s$seed
  extra=(); pp=$PYTHONPATH; xf=${XLA_FLAGS:-}; sched=${TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE:-}; u=8
  for p in ${v//+/ }; do  # a variant joins parts with "+", e.g. ln+c:utd=0.01171875
    [ "$p" = noeval ] && extra+=(--extra=--eval_every=1000000000)
    [ "$p" = swi ] && pp=/tmp/swi:$PYTHONPATH
    [ "$p" = nocb ] && xf="$xf --xla_gpu_enable_command_buffer="
    [ "$p" = bsync ] && sched=blocking_sync; [ "$p" = yield ] && sched=yield
    [ "$p" = u16 ] && extra+=(--extra=--config=updates_per_call=16) && u=16
    [ "$p" = noprec ] && extra+=(--extra=--precompile=off)
    [ "$p" = ln ] && extra+=(--extra=--config=ln_forward=pallas --extra=--config=ln_backward=pallas)
    [ "$p" = xla ] && extra+=(--extra=--config=ln_forward=xla --extra=--config=ln_backward=xla)
    [[ "$p" == c:* ]] && extra+=(--extra=--config=${p#c:})
    [[ "$p" == c:updates_per_call=* ]] && u=${p#c:updates_per_call=}
    [[ "$p" == f:* ]] && extra+=(--extra=--${p#f:})
    [ "$p" = w15 ] && extra+=(--extra=--num_workers=15 --extra=--pin_cpus=-1)
    [[ "$p" =~ ^w([0-9]+)p([0-9]+)$ ]] && extra+=(--extra=--num_workers=${BASH_REMATCH[1]} --extra=--pin_cpus=${BASH_REMATCH[2]})
  done
  XLA_FLAGS=$xf PYTHONPATH=$pp env ${sched:+TF_CUDA_PLATFORM_GPU_DEVICE_SCHEDULE=$sched} \
    python3 bench/time_to_target.py --only fastsac_async \
    --seed "$seed" --max_seconds "${MAXS:-110}" --commit "${COMMIT:-unknown}" --metrics_dir "$OUT/metrics_$run" \
    --out "$OUT/ttt_$run.json" "${extra[@]}" 2>&1 | grep -v -i warning | tail -2 | sed "s/^/$run: /"
  python3 bench/learner_runs.py --start 40 --end "${MAXS:-110}" --out "$OUT/rates_$run.json" \
    "${COMMIT:-unknown},$v,$u,$OUT/ttt_$run.json,$OUT/metrics_$run" | grep "^| ${COMMIT:-unknown}"
done
done
