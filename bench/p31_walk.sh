#!/usr/bin/env bash
# Issue 31 on the 1-GPU machine: time to walking (bench/time_to_target.py records) for CONFIG and SEEDS, then the
# first seed's policy exported as ONNX with its task sidecar (the policies shipped in policies/). Results under $OUT.
#   CONFIG=fastsac_async SEEDS="0 1" NAME=go1_walk MAXS=270 bash bench/p31_walk.sh
set -u
OUT=${OUT:-/tmp/p31_walk}; mkdir -p "$OUT/metrics"
ROBOTS="${ROBOTS:-unitree_go1 unitree_g1}" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -3 "$OUT/setup.txt"
python3 bench/time_to_target.py --only "$CONFIG" --seed $SEEDS --max_seconds "${MAXS:-300}" --commit "${COMMIT:-unknown}" \
  --metrics_dir "$OUT/metrics" --out "$OUT/ttt_$CONFIG.json" ${PROFILE:+--extra=--profile_dir=/tmp/p31_prof --extra=--profile_start=$PROFILE} 2>&1 | grep -v -i warning | tail -${TAIL:-12}
first=$(ls -d /tmp/time_to_target_runs/${CONFIG}_s${SEEDS%% *}_* | head -1)
python3 -m unilab_jax.export --logdir "$first" --format onnx --out "$OUT/$NAME.onnx" 2>&1 | tail -2
python3 - "$first" "$OUT/$NAME.json" <<'PY'
import json, sys
from unilab_jax.apps import saved_run
run = saved_run.load(sys.argv[1])
json.dump({"task": run.task, "task_overrides": run.task_overrides, "algo": run.algo, "env_steps": run.step,
           "seed": run.seed}, open(sys.argv[2], "w"), indent=1)
print("sidecar", run.task, run.step)
PY
if [ -n "${PROFILE:-}" ]; then
  python3 bench/trace_summary.py /tmp/p31_prof --threads --top 30 --out "$OUT/inrun_trace_$CONFIG.json" > /tmp/ts.txt
  head -60 /tmp/ts.txt; cp "$(find /tmp/p31_prof -name perfetto_trace.json.gz | head -1)" "$OUT/inrun_perfetto_$CONFIG.json.gz"
fi
python3 - "$first/metrics.jsonl" <<'PY'
import json, sys
rows = [json.loads(line) for line in open(sys.argv[1])]
ev = [r for r in rows if any(k.startswith("eval/") for k in r)]
print("last eval", {k: v for k, v in ev[-1].items() if k.startswith("eval/") and not isinstance(v, (list, dict))} if ev else None)
for key in ("perf/update_s", "perf/sample_s", "perf/utd"):
    vals = sorted(r[key] for r in rows if key in r)
    print(key, "median", vals[len(vals) // 2] if vals else None)
PY
