#!/usr/bin/env bash
# Issue 31 on the 2-GPU machine: the whole system, FastSAC Go1 time to walking (bench/time_to_target.py records) with
# 1 GPU + 16 cores (CUDA_VISIBLE_DEVICES=0, taskset 0-15, 13 workers) against 2 GPUs + 32 cores (--devices=2, 29
# workers), same SEEDS; each keeps its workers off 3 cores for the learner process (--pin_cpus=auto). Results under $OUT.
#   SEEDS="0" MAXS=240 bash bench/p31_whole.sh
set -u
OUT=${OUT:-/tmp/p31_whole}; mkdir -p "$OUT/metrics"
ROBOTS="unitree_go1" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -4 "$OUT/setup.txt"
common="bench/time_to_target.py --only fastsac_async --max_seconds ${MAXS:-240} --commit ${COMMIT:-unknown} --metrics_dir $OUT/metrics"
for seed in ${SEEDS:-0}; do
  CUDA_VISIBLE_DEVICES=0 taskset -c 0-15 python3 $common --seed "$seed" --num_workers 13 --out "$OUT/ttt_gpu1_cores16.json" \
    2>&1 | grep -v -i warning | tail -3 | sed "s/^/gpu1_cores16: /"
  python3 $common --seed "$seed" --num_workers 29 --extra=--devices=2 --out "$OUT/ttt_gpu2_cores32.json" \
    2>&1 | grep -v -i warning | tail -3 | sed "s/^/gpu2_cores32: /"
done
