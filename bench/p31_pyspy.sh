#!/usr/bin/env bash
# Issue 31 on the 1-GPU machine: where the learner process's host time goes, per thread, in-run (py-spy;
# docs/perf/learner_scaling.md section 13).
# Runs FastSAC Go1 (fastsac_async) as bench/p31_gil.sh's base variant for MAXS seconds (--no_stop_at_target, an empty
# compilation cache) and samples the LEARNER process: the experiment script's own process, which
# bench/time_to_target.py starts (its rollout workers and its evaluation process are spawned children of it, run
# as `python -c "from multiprocessing.spawn ..."`, and are not sampled). Seconds below count from its start:
#   every DUMP_EVERY (5) s from 30 s to T1 and after the records: `py-spy dump --native`, every thread's stack once
#   T1 (50) for DUR_PY (15) s: py-spy record --threads --idle --nonblocking at RATE_PY (200)/s: Python stacks
#                    only, read without stopping the process (no perturbation but py-spy's CPU)      -> python.raw
#   then DUR (20) s: py-spy record --threads --idle --native at RATE (20)/s: Python and native stacks, for
#                    which py-spy stops the process at each sample (GIL waits, XLA's and the driver's
#                    frames; 50/s cut a CPU run's calls 3x)                                    -> native.raw
#   around each:     /proc/PID/task/*/stat snapshots: every thread's CPU %, also the native threads (XLA's,
#                    the CUDA driver's) that py-spy does not sample
# --idle: every thread at every tick, so shares are of wall time (running, blocked, waiting for the GIL, ...).
# py-spy runs on the last core (taskset, PIN), a worker's: the learner process's cores stay its own. The learner's
# rates (bench/learner_runs.py) over 30 s-T1, each record's window and the rest tell what sampling cost the run.
# Writes $OUT/pyspy.tar.gz (records, dumps, snapshots, rates, the run's metrics), $OUT/summary_python.json and
# $OUT/summary_native.json (bench/pyspy_summary.py) and prints both summaries.
#   COMMIT=<c> bash bench/p31_pyspy.sh                        # on the GPU machine, .devr carried (bench/device_bundle.sh)
# On a CPU machine without the bundle (SETUP=0; EXTRA: flags for bench/time_to_target.py), as validated on the dev VM
# (tiny networks, so the call rate is like the GPU's; docs/perf/learner_scaling.md section 13):
#   SETUP=0 PYTHON=.venv/bin/python MAXS=100 T1=45 DUR_PY=20 DUR=15 EXTRA="--num_workers 1 --envs_per_worker 32
#     --eval_every 100000 --eval_envs 8 --extra=--config=batch_size=64 --extra=--config=utd=1.0
#     --extra=--config=learning_starts=2048 --extra=--config=critic_hidden=(16,16) --extra=--config=actor_hidden=(16,16)
#     --extra=--eval_process=on --extra=--replay_on_device=on --extra=--precompile=on" bash bench/p31_pyspy.sh
set -u
OUT=${OUT:-/tmp/p31_pyspy}; mkdir -p "$OUT"; W=$(mktemp -d)
MAXS=${MAXS:-110}; T1=${T1:-50}; DUR_PY=${DUR_PY:-15}; DUR=${DUR:-20}; RATE_PY=${RATE_PY:-200}; RATE=${RATE:-20}
DUMP_EVERY=${DUMP_EVERY:-5}; PIN=${PIN:-$(($(nproc) - 1))}
[ $((T1 + DUR_PY + DUR + 5)) -le "$MAXS" ] || { echo "p31_pyspy: T1 + DUR_PY + DUR must end 5 s before MAXS"; exit 2; }
NAME=p31_pyspy; source bench/pyspy_common.sh
go1_setup "$W"
PY=${PYTHON:-python3}
PYSPY=$(pyspy_binary) || exit 2
"$PYSPY" --version
spy=("$PYSPY"); command -v taskset > /dev/null && spy=(taskset -c "$PIN" "$PYSPY")
read -ra extra <<< "${EXTRA:-}"

"$PY" bench/time_to_target.py --only fastsac_async --seed "${SEED:-0}" \
  --max_seconds "$MAXS" --no_stop_at_target --commit "${COMMIT:-unknown}" --metrics_dir "$W/metrics" \
  --out "$W/ttt.json" "${extra[@]}" > "$W/ttt.log" 2>&1 &
ttt=$!
pid=$(learner_pid "$ttt" 0.1) || { cat "$W/ttt.log"; exit 1; }
SECONDS=0
echo "learner process $pid: $(tr '\0' ' ' < "/proc/$pid/cmdline")" | tee "$W/learner.txt"

alive() { kill -0 "$pid" 2>/dev/null; }
until_s() { while alive && [ "$SECONDS" -lt "$1" ]; do sleep 0.2; done; alive; }
snap() { { date +%s.%N; cat "/proc/$pid/task/"*/stat 2>/dev/null; } > "$W/$1"; }
dumps() {  # dumps UNTIL_SECOND
  while alive && [ "$SECONDS" -lt "$1" ]; do
    s=$SECONDS
    timeout 20 "${spy[@]}" dump --native --pid "$pid" > "$W/dump_${s}s.txt" 2>&1 \
      || timeout 20 "${spy[@]}" dump --pid "$pid" >> "$W/dump_${s}s.txt" 2>&1
    until_s $((s + DUMP_EVERY)) || return
  done
}
record() {  # record NAME SECONDS RATE MODE... : the first MODE (py-spy flags) that writes a profile
  local name=$1 secs=$2 rate=$3 mode; shift 3
  for mode in "$@"; do
    snap "stat0_$name.txt"
    timeout -s INT -k 30 $((secs + 15)) "${spy[@]}" record --threads --idle --rate "$rate" --duration "$secs" \
      --format raw $mode -o "$W/$name.raw" --pid "$pid" > "$W/$name.log" 2>&1
    snap "stat1_$name.txt"
    if [ -s "$W/$name.raw" ]; then echo "$name: rate $rate ${mode:-(blocking)}" | tee -a "$W/modes.txt"; return; fi
    echo "$name: py-spy record ${mode:-(blocking)} failed: $(grep -v '^ ' "$W/$name.log" | tail -2 | tr '\n' ' ')"
    alive || return
  done
}

until_s 30 && dumps "$T1"
ps -eo pid,ppid,psr,pcpu,nlwp,args > "$W/ps.txt" 2>/dev/null
record python "$DUR_PY" "$RATE_PY" --nonblocking ""
t2=$SECONDS
record native "$DUR" "$RATE" --native --native
t3=$SECONDS
dumps $((MAXS - 5))
wait "$ttt"; tail -3 "$W/ttt.log"

for win in "pre 30 $T1" "python $T1 $t2" "native $t2 $t3" "post $((t3 + 1)) $MAXS"; do
  read -r name a b <<< "$win"
  "$PY" bench/learner_runs.py --start "$a" --end "$b" --out "$W/rates_$name.json" \
    "${COMMIT:-unknown},pyspy_$name,${U:-8},$W/ttt.json,$W/metrics" | grep "^| ${COMMIT:-unknown}"
done
for name in python native; do
  [ -s "$W/$name.raw" ] || continue
  echo "== $(grep "^$name:" "$W/modes.txt")"
  "$PY" bench/pyspy_summary.py "$W/$name.raw" --taskstat "$W/stat0_$name.txt" "$W/stat1_$name.txt" \
    --out "$W/summary_$name.json" && cp "$W/summary_$name.json" "$OUT/"
done
tar czf "$OUT/pyspy.tar.gz" -C "$W" . && rm -rf "$W"
