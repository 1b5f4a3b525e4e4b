#!/usr/bin/env bash
# Several bench/time_to_target.py runs side by side on one multi-GPU host, each lane an "H100 + 16 cores" of its own:
# lane i gets GPU i (CUDA_VISIBLE_DEVICES) and cores [i*CORES, (i+1)*CORES) (taskset; the runtime sizes its workers
# and pins them from that affinity), and runs its items one after the other.
#   LANES="g1_fastsac:0:420 ; g1_fastsac:1:420 ; fastsac_async:0:150 fastsac_async:1:150" COMMIT=<c> bash bench/lanes.sh
# LANES: lanes separated by ';', each a space-separated list of CONFIG:SEED:MAX_SECONDS. DEADLINE (s from the
# script's start, default 540) caps every run: an item gets min(MAX_SECONDS, what is left before DEADLINE minus a
# 30 s margin for its stop) and is skipped when that is below 60 s, so the whole command ends inside a 10-minute
# call; a run cut short records its budget (a lower bound in --report). ROBOTS: the archives to unpack
# (bench/device_setup.sh; robots unpacked and wheels copied by an earlier call on the same warm machine stay); SETUP=0
# skips that set-up. Under $OUT: machine.txt and lanes.tgz: ttt/ttt_<config>_s<seed>.json (a record file per run:
# no two processes append to one file), ttt/lanes.jsonl (each run's GPU, cores and start), logs/ (each lane's and
# run's), metrics/ (half-second means).
set -u
OUT=${OUT:-/tmp/lanes}; mkdir -p "$OUT"; W=$(mktemp -d); mkdir -p "$W/metrics" "$W/logs" "$W/ttt"
START=$(date +%s); DEADLINE=${DEADLINE:-540}; CORES=${CORES:-16}
if [ "${SETUP:-1}" = 1 ]; then
  source bench/device_setup.sh > "$OUT/machine.txt" 2>&1 || { cat "$OUT/machine.txt"; exit 1; }
fi
{ lscpu | grep -E "Model name|^CPU\(s\)|Thread|Socket"; nvidia-smi --query-gpu=name,memory.total --format=csv; } \
  >> "$OUT/machine.txt" 2>&1
head -5 "$OUT/machine.txt"
ngpu=$(nvidia-smi -L | wc -l); ncpu=$(nproc)

run_lane() {  # lane index, items
  local i=$1; shift
  local first=$((i * CORES)) last=$(((i + 1) * CORES - 1)) item cfg seed cap left
  for item in "$@"; do
    IFS=: read -r cfg seed cap <<< "$item"
    left=$((START + DEADLINE - 30 - $(date +%s)))
    if [ "$left" -lt 60 ]; then echo "lane $i: $cfg seed $seed skipped ($left s left)"; continue; fi
    [ "$cap" -gt "$left" ] && cap=$left
    echo "lane $i: $cfg seed $seed, $cap s, from $(($(date +%s) - START)) s"
    printf '{"config": "%s", "seed": %s, "gpu": %s, "cores": "%s-%s", "started_s": %s, "max_seconds": %s}\n' \
      "$cfg" "$seed" "$i" "$first" "$last" "$(($(date +%s) - START))" "$cap" >> "$W/ttt/lanes.jsonl"
    env CUDA_VISIBLE_DEVICES="$i" taskset -c "$first-$last" python3 bench/time_to_target.py --only "$cfg" \
      --seed "$seed" --max_seconds "$cap" --commit "${COMMIT:-unknown}" --runs_dir "$W/runs_$i" \
      --metrics_dir "$W/metrics" --out "$W/ttt/ttt_${cfg}_s${seed}.json" > "$W/logs/${cfg}_s${seed}.log" 2>&1
    echo "lane $i: $cfg seed $seed ended at $(($(date +%s) - START)) s: $(grep -v -i warning "$W/logs/${cfg}_s${seed}.log" | tail -1)"
  done
}

i=0; pids=()
IFS=';' read -ra lanes <<< "${LANES:?LANES is required}"
[ "${#lanes[@]}" -le "$ngpu" ] || { echo "lanes: ${#lanes[@]} lanes, $ngpu GPUs"; exit 2; }
[ $((${#lanes[@]} * CORES)) -le "$ncpu" ] || { echo "lanes: ${#lanes[@]} lanes x $CORES cores, $ncpu cores"; exit 2; }
for lane in "${lanes[@]}"; do
  read -ra items <<< "$lane"
  run_lane "$i" "${items[@]}" > "$W/logs/lane_$i.log" 2>&1 &
  pids+=($!); i=$((i + 1))
done
wait "${pids[@]}"
cat "$W"/logs/lane_*.log
for f in "$W"/metrics/*.jsonl; do [ -e "$f" ] && python3 bench/compact_metrics.py --wall_bin 0.5 "$f" "$f.gz" && rm "$f"; done
python3 - "$W/ttt" <<'PY'
import glob, json, sys
for path in sorted(glob.glob(sys.argv[1] + "/ttt_*.json")):
    for r in json.load(open(path))["records"]:
        print(r.get("config"), r.get("seed"), "walking", r.get("time_to_walking_s"), "at",
              r.get("env_steps_at_walking"), "stopped_by", r.get("stopped_by"), "rc", r.get("returncode"))
PY
tar czf "$OUT/lanes.tgz" -C "$W" logs metrics ttt && rm -rf "$W"
