#!/usr/bin/env bash
# Issue 37 on the H100 + 16 cores machine: ROLE (hora: teacher then student; ppo: the privileged-actor PPO) with
# the settings SETTING, one run per seed of SEEDS side by side (the cores split between them), each stopped at
# MAXS seconds (SIGTERM: a final checkpoint and evaluation); then one record per seed and role in $OUT/allegro.json
# (bench/allegro_results.py; copy it into bench/results/h100/phase3/allegro.json with --out there) and the runs'
# metrics under $OUT/runs. Bundle: ROBOTS="wonik_allegro" bash ../shared/device/prepare.sh, carry .device.
#   ROLE=hora SETTING=std SEEDS="0 1 2" COMMIT=$(git rev-parse --short HEAD) bash bench/p37_allegro.sh
# A second call on the same warm machine with RESUME=1 continues the runs (runs/p37_* stay there); FINAL_EVAL=N and
# VIDEO=1 (below) evaluate the last checkpoints at length and film the first seed, EVAL_ONLY=1 without training.
# Under $OUT: allegro.json and p37_runs.tgz (logs, metrics, final evaluations, videos).
# Settings (named options of the recipes, whose defaults stay): base; fixed_lr (lr_schedule=fixed at LR);
# std (the action std's bound falls to STD over SCHED env steps); grasp (episodes start from the grasp cache);
# all (the three); steady (all, and a fall costs FALL (default -40) instead of the task's -10: the teacher of `all`
# turns objects at 0.31 rad/s, past the 0.2 goal, but drops them 57% into an episode against the 0.8 goal, so the
# reward is moved toward keeping the object); hold (steady, and HORA's object-velocity penalty back at LINVEL
# (default -0.3; the recipes set it to 0): from the grasp cache the teachers drop objects as early as a scripted
# gait that pushes them off the palm, docs/RESULTS.md); held (hold, the episodes starting from the grasps that keep
# their object through a still episode: grasp_cache=held, tasks/allegro_grasps.py); custom (EXTRA's flags).
# EXTRA is appended to every setting. NAME (default SETTING) names the runs and their records: a run resumed under
# another setting keeps its NAME (the two-step schedule: NAME=held_relaxed SETTING=held for the first call, then
# NAME=held_relaxed SETTING=held FALL=-10 LINVEL=0 RESUME=1 with a larger TEACHER_STEPS).
set -u
OUT=${OUT:-/tmp/p37}; mkdir -p "$OUT/runs"
if [ "${SETUP:-1}" = 1 ]; then  # SETUP=0: set up already (bench/lane_commands.sh)
  ROBOTS="wonik_allegro" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
  head -3 "$OUT/setup.txt"
fi
# side by side on one GPU: each process allocates what it uses, not 75% of the memory (three would not fit)
export XLA_PYTHON_CLIENT_PREALLOCATE=false
# the record's machine: this GPU's name, the host's GPU count and the cores this script may use (taskset)
MACHINE=${MACHINE:-"$(nvidia-smi --query-gpu=name --format=csv,noheader | head -1) x$(nvidia-smi -L | wc -l) host: \
1 GPU + $(nproc) cores"}
SEEDS=${SEEDS:-"0 1 2"}; ROLE=${ROLE:-hora}; SETTING=${SETTING:-base}; NAME=${NAME:-$SETTING}; MAXS=${MAXS:-450}
workers=$(( ($(nproc) - 1) / $(echo $SEEDS | wc -w) ))  # 16 cores, 3 seeds: 5 workers each
fixed="--config lr_schedule=fixed --config learning_rate=${LR:-3e-4}"
std="--config final_std=${STD:-0.3} --config schedule_steps=${SCHED:-4000000}"
grasp="--task_config=grasp_cache=builtin --task_config=reset_press=0"
all="$fixed $std $grasp"
steady="$all --task_config=scale_fall=${FALL:--40}"
hold="$steady --task_config=scale_object_linvel=${LINVEL:--0.3}"
case $SETTING in
  base) S="" ;; fixed_lr) S=$fixed ;; std) S=$std ;; grasp) S=$grasp ;; all) S=$all ;;
  steady) S=$steady ;;
  hold) S=$hold ;;
  held) S=${hold/grasp_cache=builtin/grasp_cache=held} ;;
  custom) S="" ;;
  *) echo "SETTING must be base, fixed_lr, std, grasp, all, steady, hold, held or custom"; exit 2 ;;
esac
common="--num_workers=$workers --envs_per_worker=${ENVS:-64} --eval_every=${EVAL_EVERY:-1000000} \
  --eval_envs=${EVAL_ENVS:-128} $S ${EXTRA:-} ${RESUME:+--resume}"
if [ "$ROLE" = hora ]; then
  cmd="python3 experiments/hora_allegro.py --teacher_steps=${TEACHER_STEPS:-4000000} \
    --student_steps=${STUDENT_STEPS:-1000000} $common"
else
  cmd="python3 experiments/ppo_allegro_rotate.py --total_steps=${TOTAL_STEPS:-5000000} $common"
fi
echo "$ROLE $NAME ($SETTING) seeds $SEEDS, $workers workers each: $cmd"
dirs() {  # the logdirs of seed $1's runs (HORA: teacher and student; PPO: the run)
  local d=runs/p37_${ROLE}_${NAME}_s$1
  if [ "$ROLE" = hora ]; then echo $d/teacher $d/student; else echo $d; fi
}
if [ "${EVAL_ONLY:-0}" != 1 ]; then
  for s in $SEEDS; do
    timeout -s TERM "$MAXS" $cmd --seed=$s --logdir=runs/p37_${ROLE}_${NAME}_s$s \
      > "$OUT/runs/${ROLE}_${NAME}_s$s.log" 2>&1 &
  done
  wait
fi
# FINAL_EVAL=N: the deterministic policy of each run's last two checkpoints over N episodes (python -m
# unilab_jax.play, one process each, side by side on the CPU cores), as final_eval_<step>.json in the logdir, which
# bench/allegro_results.py reads (the record's final_evals and neighbour_gap_rad_s). Per-episode rates spread by
# ~0.8 rad/s, so N ~ 2000 makes the standard error ~0.02. EVAL_ONLY=1 skips the training (a call of its own).
if [ "${FINAL_EVAL:-0}" -gt 0 ]; then
  for s in $SEEDS; do for d in $(dirs $s); do for c in $(ls $d/checkpoints 2>/dev/null | sort -n | tail -2); do
    [ -f $d/final_eval_$c.json ] && continue
    (JAX_PLATFORMS=cpu timeout "${FINAL_S:-480}" python3 -m unilab_jax.play --logdir $d --checkpoint $c \
      --episodes "$FINAL_EVAL" --seed 7 > $d/final_eval_$c.part 2>> "$OUT/runs/final_eval.log" \
      && mv $d/final_eval_$c.part $d/final_eval_$c.json) &
  done; done; done
  wait
fi
for s in $SEEDS; do
  d=runs/p37_${ROLE}_${NAME}_s$s; runs=""
  for role in teacher student; do [ -f $d/$role/summary.json ] && runs="$runs --run $role=$d/$role"; done
  [ -f $d/summary.json ] && runs="--run ppo=$d"
  tail -3 "$OUT/runs/${ROLE}_${NAME}_s$s.log" 2>/dev/null
  python3 bench/allegro_results.py --out "$OUT/allegro.json" --setting "$NAME" --seed "$s" \
    --commit "${COMMIT:-unknown}" --machine "$MACHINE" --command "$cmd" $runs
  mkdir -p "$OUT/runs/s$s" && (cd $d && find . \( -name metrics.jsonl -o -name summary.json -o -name hora_summary.json \
    -o -name 'final_eval_*.json' \) -exec cp --parents {} "$OUT/runs/s$s" \;)
done
# VIDEO=1: the first seed's policies turning each object shape (OpenCV's MPEG-4 on the GPU machine; re-encode here
# with python bench/device_video.py --transcode SRC DST)
if [ "${VIDEO:-0}" = 1 ]; then
  for d in $(dirs ${SEEDS%% *}); do for shape in cylinder box; do
    JAX_PLATFORMS=cpu python3 bench/device_video.py --logdir $d --out "$OUT/runs/$(basename $d)_$shape.mp4" --steps 400 \
      --width 480 --height 360 --task_config "shapes=('$shape',)" 2>> "$OUT/runs/video.log" | grep -E '"(rotation_rate|video)"'
  done; done
fi
python3 bench/allegro_results.py --out "$OUT/allegro.json" --report
# one archive of logs, metrics, final evaluations and videos (a call returns at most 8 files, 2 folders down)
tar czf "$OUT/p37_runs.tgz" -C "$OUT" runs && rm -rf "$OUT/runs"
