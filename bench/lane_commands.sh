#!/usr/bin/env bash
# Different bench scripts side by side on one multi-GPU host, each lane an "H100 + 16 cores" of its own: lane i runs
# the i-th argument (a shell command) with GPU i (CUDA_VISIBLE_DEVICES), cores [i*CORES, (i+1)*CORES) (taskset),
# SETUP=0 (set up once here, before the lanes start: bench/device_setup.sh with ROBOTS) and OUT=<lane folder>.
# bench/lanes.sh runs bench/time_to_target.py items; this one runs whole scripts (bench/p33_terrain.sh,
# bench/p37_allegro.sh), e.g. three G1 rough seeds and the Allegro teachers:
#   ROBOTS="unitree_g1 wonik_allegro" bash bench/lane_commands.sh \
#     'CONFIG=g1_rough_fastsac SEEDS=0 MAXS=470 bash bench/p33_terrain.sh' ... \
#     'ROLE=hora SETTING=held bash bench/p37_allegro.sh'
# Under $OUT: machine.txt and lanes.tgz (lane_<i>/: the lane's own OUT, and lane_<i>.log, its output).
set -u
OUT=${OUT:-/tmp/lane_commands}; mkdir -p "$OUT"; W=$(mktemp -d); CORES=${CORES:-16}
[ "$#" -ge 1 ] || { echo "lane_commands: give one command per lane"; exit 2; }
source bench/device_setup.sh > "$OUT/machine.txt" 2>&1 || { cat "$OUT/machine.txt"; exit 1; }
{ lscpu | grep -E "Model name|^CPU\(s\)"; nvidia-smi --query-gpu=name,memory.total --format=csv; } \
  >> "$OUT/machine.txt" 2>&1
head -5 "$OUT/machine.txt"
ngpu=$(nvidia-smi -L | wc -l)
[ "$#" -le "$ngpu" ] || { echo "lane_commands: $# lanes, $ngpu GPUs"; exit 2; }
[ $(($# * CORES)) -le "$(nproc)" ] || { echo "lane_commands: $# lanes x $CORES cores, $(nproc) cores"; exit 2; }
i=0; pids=(); cmds=("$@")
for cmd in "$@"; do
  mkdir -p "$W/lane_$i"
  (export SETUP=0 OUT="$W/lane_$i" CUDA_VISIBLE_DEVICES=$i
   taskset -c "$((i * CORES))-$(((i + 1) * CORES - 1))" bash -c "$cmd") > "$W/lane_$i.log" 2>&1 &
  pids+=($!); i=$((i + 1))
done
wait "${pids[@]}"
for ((j = 0; j < i; j++)); do echo "== lane $j: ${cmds[$j]}"; tail -${TAIL:-25} "$W/lane_$j.log"; done
tar czf "$OUT/lanes.tgz" -C "$W" . && rm -rf "$W"
