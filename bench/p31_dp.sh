#!/usr/bin/env bash
# Issue 31 on the 2-GPU machine: the data-parallel FastSAC learner (Go1 sizes, bf16, 8192 rows per device), one device
# against two, with XLA's defaults and with the variants in VARIANTS (name=XLA flags added); the default's 3 steady
# calls per device count traced and summarised per device (PROFILE=0: not traced); then the critic ensemble split over
# the devices (--device_split critics, the minibatch of 8192 whole on each). Results under $OUT.
#   VARIANTS="nocb=--xla_gpu_enable_command_buffer=" bash bench/p31_dp.sh
set -u
OUT=${OUT:-/tmp/p31_dp}; mkdir -p "$OUT"
ROBOTS=robotiq_2f85 source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -4 "$OUT/setup.txt"
base="--xla_gpu_enable_triton_gemm=false"
so() {  # name, extra XLA flags, extra args
  XLA_FLAGS="$base $2" python3 bench/scale_out.py learner --devices 1 2 --batch_per_device 8192 \
    --compute_dtype bfloat16 --out "$OUT/scale_out_learner_$1.json" ${3:-} 2>&1 | grep -A3 "^devices" | sed "s/^/$1: /"
}
if [ "${PROFILE:-1}" = 0 ]; then so default ""; else
  so default "" "--profile_dir /tmp/p31_dp_prof"
  for n in 1 2; do
    python3 bench/trace_summary.py /tmp/p31_dp_prof/devices_$n --per_device --top 25 --out "$OUT/trace_devices_$n.json" \
      > "$OUT/trace_devices_$n.txt" 2>&1
    echo "== devices $n"; head -45 "$OUT/trace_devices_$n.txt"
  done
fi
so critics "" "--device_split critics"
for v in ${VARIANTS:-}; do so "${v%%=*}" "${v#*=}"; done
