#!/usr/bin/env bash
# Issue 37 on the H100 + 16 cores machine: ROLE (hora: teacher then student; ppo: the privileged-actor PPO) with
# the settings SETTING, one run per seed of SEEDS side by side (the cores split between them), each stopped at
# MAXS seconds (SIGTERM: a final checkpoint and evaluation); then one record per seed and role in $OUT/allegro.json
# (bench/allegro_results.py; copy it into bench/results/h100/phase3/allegro.json with --out there) and the runs'
# metrics under $OUT/runs. Bundle: ROBOTS="wonik_allegro" bash ../shared/device/prepare.sh, carry .device.
#   ROLE=hora SETTING=std SEEDS="0 1 2" COMMIT=$(git rev-parse --short HEAD) bash bench/p37_allegro.sh
# A second call on the same warm machine with RESUME=1 continues the runs (runs/p37_* stay there).
# Settings (named options of the recipes, whose defaults stay): base; fixed_lr (lr_schedule=fixed at LR);
# std (the action std's bound falls to STD over SCHED env steps); grasp (episodes start from the grasp cache);
# all (the three); custom (EXTRA's flags). EXTRA is appended to every setting.
set -u
OUT=${OUT:-/tmp/p37}; mkdir -p "$OUT/runs"
ROBOTS="wonik_allegro" source bench/device_setup.sh > "$OUT/setup.txt" 2>&1 || { cat "$OUT/setup.txt"; exit 1; }
head -3 "$OUT/setup.txt"
# side by side on one GPU: each process allocates what it uses, not 75% of the memory (three would not fit)
export XLA_PYTHON_CLIENT_PREALLOCATE=false
SEEDS=${SEEDS:-"0 1 2"}; ROLE=${ROLE:-hora}; SETTING=${SETTING:-base}; MAXS=${MAXS:-450}
workers=$(( ($(nproc) - 1) / $(echo $SEEDS | wc -w) ))  # 16 cores, 3 seeds: 5 workers each
fixed="--config lr_schedule=fixed --config learning_rate=${LR:-3e-4}"
std="--config final_std=${STD:-0.3} --config schedule_steps=${SCHED:-4000000}"
grasp="--task_config=grasp_cache=builtin --task_config=reset_press=0"
case $SETTING in
  base) S="" ;; fixed_lr) S=$fixed ;; std) S=$std ;; grasp) S=$grasp ;; all) S="$fixed $std $grasp" ;;
  custom) S="" ;; *) echo "SETTING must be base, fixed_lr, std, grasp, all or custom"; exit 2 ;;
esac
common="--num_workers=$workers --envs_per_worker=${ENVS:-64} --eval_every=${EVAL_EVERY:-1000000} \
  --eval_envs=${EVAL_ENVS:-128} $S ${EXTRA:-} ${RESUME:+--resume}"
if [ "$ROLE" = hora ]; then
  cmd="python3 experiments/hora_allegro.py --teacher_steps=${TEACHER_STEPS:-4000000} \
    --student_steps=${STUDENT_STEPS:-1000000} $common"
else
  cmd="python3 experiments/ppo_allegro_rotate.py --total_steps=${TOTAL_STEPS:-5000000} $common"
fi
echo "$ROLE $SETTING seeds $SEEDS, $workers workers each: $cmd"
for s in $SEEDS; do
  timeout -s TERM "$MAXS" $cmd --seed=$s --logdir=runs/p37_${ROLE}_${SETTING}_s$s > "$OUT/runs/${ROLE}_${SETTING}_s$s.log" 2>&1 &
done
wait
for s in $SEEDS; do
  d=runs/p37_${ROLE}_${SETTING}_s$s; runs=""
  for role in teacher student; do [ -f $d/$role/summary.json ] && runs="$runs --run $role=$d/$role"; done
  [ -f $d/summary.json ] && runs="--run ppo=$d"
  tail -3 "$OUT/runs/${ROLE}_${SETTING}_s$s.log"
  python3 bench/allegro_results.py --out "$OUT/allegro.json" --setting "$SETTING" --seed "$s" \
    --commit "${COMMIT:-unknown}" --command "$cmd" $runs
  mkdir -p "$OUT/runs/s$s" && (cd $d && find . \( -name metrics.jsonl -o -name summary.json -o -name hora_summary.json \) \
    -exec cp --parents {} "$OUT/runs/s$s" \;)
done
python3 bench/allegro_results.py --out "$OUT/allegro.json" --report
