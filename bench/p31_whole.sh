#!/usr/bin/env bash
# Issue 31 on the 2-GPU machine: the whole system, FastSAC Go1 time to walking (bench/time_to_target.py records), same
# SEEDS, one record file per setup in VARIANTS (default: all three, the hardware plot's points):
#   gpu1_cores16  1 GPU + 16 cores (CUDA_VISIBLE_DEVICES=0, taskset 0-15, 13 workers)
#   gpu1_cores32  1 GPU + 32 cores (CUDA_VISIBLE_DEVICES=0, 29 workers)
#   gpu2_cores32  2 GPUs + 32 cores (--devices=2, the learner split over them as SPLIT says: batch | critics; 29 workers)
# Each keeps its workers off 3 cores for the learner process (--pin_cpus=auto). Results under $OUT.
#   SEEDS="0" MAXS=240 SPLIT=critics VARIANTS="gpu1_cores16 gpu2_cores32" bash bench/p31_whole.sh
set -u
OUT=${OUT:-/tmp/p31_whole}; mkdir -p "$OUT/metrics"
ROBOTS="unitree_go1" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -4 "$OUT/setup.txt"
common="bench/time_to_target.py --only fastsac_async --max_seconds ${MAXS:-240} --commit ${COMMIT:-unknown} --metrics_dir $OUT/metrics"
for seed in ${SEEDS:-0}; do
for v in ${VARIANTS:-gpu1_cores16 gpu1_cores32 gpu2_cores32}; do
  case $v in
    gpu1_cores16) pre=(env CUDA_VISIBLE_DEVICES=0 taskset -c 0-15); args=(--num_workers 13) ;;
    gpu1_cores32) pre=(env CUDA_VISIBLE_DEVICES=0); args=(--num_workers 29) ;;
    gpu2_cores32) pre=(env); args=(--num_workers 29 --extra=--devices=2 --extra=--device_split="${SPLIT:-batch}") ;;
    *) echo "unknown variant $v (gpu1_cores16, gpu1_cores32, gpu2_cores32)"; exit 2 ;;
  esac
  "${pre[@]}" python3 $common --seed "$seed" "${args[@]}" --out "$OUT/ttt_$v.json" \
    2>&1 | grep -v -i warning | tail -3 | sed "s/^/$v: /"
done
done
