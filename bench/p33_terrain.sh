#!/usr/bin/env bash
# Issue 33 on the 1-GPU machine (H100 + 16 cores): the rough-terrain recipes to the rough-terrain walking criterion.
#   CONFIG=go1_rough_fastsac SEEDS="0" MAXS=480 bash bench/p33_terrain.sh
# CONFIG: a rough configuration of bench/time_to_target.py (go1_rough_ppo, go1_rough_fastsac, go2_rough_flashsac,
# g1_rough_fastsac; the MJX baseline mjx_go1_rough_ppo, mjx_go1_rough_fastsac). Carry .devr (bench/device_bundle.sh)
# and, for the videos, .gl (docs/dev/GPU_RUNS.md). Under $OUT:
#   terrain.json       one record per run (robot, algo, seed, time_to_walking_rough_s, max_terrain_level and its
#                      wall_s / step, max_terrain_level_fraction, git_commit, the evaluation curve): append its records
#                      to bench/results/h100/phase3/terrain.json
#   metrics/*.jsonl.gz each run's metrics; curves.json the mean terrain level against time (bench/terrain_curves.py)
#   <config>_s<seed>_stairs_up.mp4, ..._stairs_down.mp4 (MPEG-4 Part 2 by OpenCV; bench/device_video.py --transcode
#                      re-encodes them as H.264 here): the first seed's policy on each stairs type at the
#                      evaluation's first level (runtime configurations only: the MJX loop keeps no checkpoint;
#                      VIDEO=0 skips them)
# One 10-minute command holds one run of MAXS seconds (default 480) plus ~1 minute of set-up and videos; a run that
# misses the criterion within MAXS records the budget (a lower bound in --report). RESUME=1 in the next call on the
# same warm machine continues each seed's run from its final checkpoint for another MAXS seconds, its clock going on
# (bench/time_to_target.py --resume; the new process's start-up counted again): the 600 s / 900 s goals over two
# calls. Keep both calls' terrain.json records; the report counts the last record of each run. The workers' curricula
# (terrain levels, command ranges) are not in the checkpoint: they start again from the initial levels, a handicap the
# resumed time includes (the criterion's evaluation uses fixed upper-half levels, whatever the curriculum).
set -u
OUT=${OUT:-/tmp/p33_terrain}; mkdir -p "$OUT/metrics"
if [ "${SETUP:-1}" = 1 ]; then  # SETUP=0: set up already (runs side by side, one CUDA_VISIBLE_DEVICES and taskset each)
  ROBOTS="${ROBOTS:-unitree_go1 unitree_go2 unitree_g1}" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
  head -3 "$OUT/setup.txt"
fi
RUNS=${RUNS_DIR:-/tmp/time_to_target_runs}
extra=(); for x in ${EXTRA:-}; do extra+=("--extra=$x"); done  # EXTRA: flags for the experiment, space-separated
# The runtime's off-policy runs keep their replay across the RESUME=1 call (--keep_replay: the rings written at the
# stop, copied back by --resume; ~3 GB, so the stop's grace before a SIGKILL is 90 s): resumed from an empty replay, the
# three G1 runs at 63b0c75 fell from mean level 1.3-2.1 to 0.4-0.7 and were back at 1.2-1.4 by 865-892 s.
# KEEP_REPLAY=0: off.
case $CONFIG in
  mjx_*|*_ppo) ;;
  *) [ "${KEEP_REPLAY:-1}" = 1 ] && extra+=("--extra=--keep_replay" --stop_grace 90) ;;
esac
python3 bench/time_to_target.py --only "$CONFIG" --seed $SEEDS --max_seconds "${MAXS:-480}" --commit "${COMMIT:-unknown}" \
  --runs_dir "$RUNS" --metrics_dir "$OUT/metrics" --out "$OUT/terrain.json" "${extra[@]}" \
  ${RESUME:+--resume} 2>&1 \
  | grep -v -i warning | tail -${TAIL:-14}
python3 bench/terrain_curves.py "$OUT/metrics" --out "$OUT/curves.json"
# a row per learner call is ~16 MB gzipped in 10 minutes: the training rows as half-second means (the curves keep)
for f in "$OUT"/metrics/*.jsonl; do python3 bench/compact_metrics.py --wall_bin 0.5 "$f" "$f.gz" && rm "$f"; done
python3 - "$OUT/terrain.json" <<'PY'
import json, sys
for r in json.load(open(sys.argv[1]))["records"]:
    print({k: r.get(k) for k in ("config", "robot", "algo", "seed", "time_to_walking_rough_s", "max_terrain_level",
                                 "max_terrain_level_wall_s", "max_terrain_level_fraction", "stopped_by", "returncode")})
    print("  last eval", r["evals"][-1] if r.get("evals") else None)
PY
first=$(ls -d "$RUNS/${CONFIG}_s${SEEDS%% *}_"* 2>/dev/null | tail -1)
if [ "${VIDEO:-1}" = 1 ] && [ -n "$first" ] && ls "$first" | grep -q -i checkpoint; then
  for stairs in stairs_up stairs_down; do
    # the GPU machine has OpenCV, not imageio-ffmpeg: MPEG-4 Part 2 there, to re-encode here
    # (python bench/device_video.py --transcode SRC DST)
    python3 bench/device_video.py --logdir "$first" --out "$OUT/${CONFIG}_s${SEEDS%% *}_$stairs.mp4" \
      --steps "${STEPS:-500}" --task_config "terrain_columns=('$stairs',)" 2>&1 | grep -v -i warning | tail -12
  done
fi
