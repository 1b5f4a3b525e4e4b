#!/usr/bin/env bash
# Issue 31 on the 1-GPU machine: where FastSAC Go1's start-up goes before its first update (docs/perf/learner_scaling.md
# section 18: learner state ready 8-10 s after the start on the H100 machine, 1.4-2 s on the CPU; then 10-13 s of
# compiling the update).
# One run of fastsac_async (bench/time_to_target.py, an empty compilation cache, MAXS seconds, JAX_LOG_COMPILES=1 so its
# log lists every compile and its seconds) while py-spy samples the LEARNER process (the experiment script's own) from
# its first moments: Python stacks of every thread at RATE/s, read without stopping it (--nonblocking --idle), in two
# windows, `init` (its first T1 s: imports, the backend's start, the learner state, the workers' start) and `compile`
# (the next DUR s: the update's compile while the rings fill, the first updates). Under $OUT: startup.tar.gz (the
# records, the run's log and time-to-target record) and summary_{init,compile}.json (bench/pyspy_summary.py; each
# thread's inclusive Python frames tell which calls the seconds went to).
#   COMMIT=<c> bash bench/p31_startup.sh                       # on the GPU machine, .devr carried (bench/device_bundle.sh)
# On a CPU machine without the bundle: SETUP=0 PYTHON=.venv/bin/python EXTRA="--num_workers 1 --envs_per_worker 16"
set -u
OUT=${OUT:-/tmp/p31_startup}; mkdir -p "$OUT"; W=$(mktemp -d)
MAXS=${MAXS:-35}; T1=${T1:-11}; DUR=${DUR:-15}; RATE=${RATE:-100}
[ $((T1 + DUR + 3)) -le "$MAXS" ] || { echo "p31_startup: T1 + DUR must end 3 s before MAXS"; exit 2; }
NAME=p31_startup; source bench/pyspy_common.sh
go1_setup "$W"
PY=${PYTHON:-python3}
PYSPY=$(pyspy_binary) || exit 2
read -ra extra <<< "${EXTRA:-}"

JAX_LOG_COMPILES=1 "$PY" bench/time_to_target.py --only fastsac_async --seed "${SEED:-0}" --max_seconds "$MAXS" \
  --no_stop_at_target --commit "${COMMIT:-unknown}" --runs_dir "$W/runs" --out "$W/ttt.json" "${extra[@]}" \
  > "$W/ttt.log" 2>&1 &
ttt=$!
pid=$(learner_pid "$ttt" 0.02) || { cat "$W/ttt.log"; exit 1; }
echo "learner process $pid, found $(ps -o etimes= -p "$pid" | tr -d ' ') s after its start"
for win in "init $T1" "compile $DUR"; do
  read -r name secs <<< "$win"
  timeout -s INT -k 20 $((secs + 10)) "$PYSPY" record --threads --idle --nonblocking --rate "$RATE" --duration "$secs" \
    --format raw -o "$W/$name.raw" --pid "$pid" > "$W/$name.log" 2>&1
done
wait "$ttt"; tail -2 "$W/ttt.log"
cp "$W"/runs/*/stdout.log "$W/run_stdout.log" 2>/dev/null
grep -E "after the start|update compiled" "$W/run_stdout.log"
echo "compiles over 1 s: $(grep -cE 'Finished XLA compilation.* in ([1-9][0-9]*\.|[1-9]\.)' "$W/run_stdout.log")"
grep -E "Finished XLA compilation" "$W/run_stdout.log" | sed -E 's/.*compilation of (.*) in ([0-9.]+) sec.*/\2 \1/' \
  | sort -rn | head -8
for name in init compile; do
  [ -s "$W/$name.raw" ] || { echo "$name: no profile ($(tail -1 "$W/$name.log"))"; continue; }
  "$PY" bench/pyspy_summary.py "$W/$name.raw" --out "$W/summary_$name.json" > "$W/summary_$name.txt" \
    && cp "$W/summary_$name.json" "$OUT/" && echo "== $name" && head -30 "$W/summary_$name.txt"
done
rm -rf "$W/runs"
tar czf "$OUT/startup.tar.gz" -C "$W" . && rm -rf "$W"
