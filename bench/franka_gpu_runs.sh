# The README's Franka GPU commands (RLPD / SAC, peg insertion / pick-and-place) as named jobs run side by side on
# one GPU machine, each followed by 40-episode evaluations of its last three checkpoints; logs, compacted metrics
# (bench/compact_metrics.py) and evaluations go to $OUT. On the GPU machine, after bench/device_setup.sh:
#   JOB_TIMEOUT=360 COMMIT=<this checkout's commit> bash bench/franka_gpu_runs.sh rlpd_peg_s0 rlpd_peg_s1
# (a job takes JOB_TIMEOUT plus up to 120 s of evaluations: with setup, keep JOB_TIMEOUT <= 360 in a 10-minute call: 400 ran past 560 s)
# JOB = rlpd_peg_sN | rlpdflow_peg_sN | rlpdflow_peg_images_sN | sac_peg_sN | rlpd_pick_sN | sac_pick_sN | sacflow_pick_sN | rlpd_peg_images_sN | rlpd_pick_images_sN
#       | rlpd_peg_images_asym_sN | rlpd_pick_images_asym_sN | rlpd_pick_images_pair_sN
#       | rlpd_peg_images_rt_sN | rlpd_pick_images_dense_sN
#       | rlpd_pick_images_gate_sN | rlpd_pick_images_gate_pair_sN; SPEED (default 10) sets --speed, TOTAL (default 36000: 60 robot-minutes at 10 Hz)
#       --total_steps (rlpdflow_peg's update is ~2x RLPD's on the CPU: TOTAL=18000 compares the two at 30 robot-minutes
#       inside one call).
# _pair: 6 Franka + 6 UR5e robots alternating in the inventory (both kinds train and evaluate), one policy; its
# 40-episode evaluations run on each arm (..._eval40_<step>.json the Franka, ..._ur5e_eval40_<step>.json the UR5e).
# rlpdflow_peg: rlpd_peg's command (demonstrations, prior data, critics, flags) with SAC Flow's actor (--algo=rlpd_flow),
# the issue-32 comparison of the two actors at the same robot time; rlpdflow_peg_images the same from images
# (rlpd_peg_images's command with SAC Flow's actor).
# _dense: image RLPD pick-and-place with the task's potential-based shaping (--dense_reward, as peg insertion's runs)
# at utd 10, the actor every 10th gradient step (one actor step per env step, as the sparse pick's 20 / 20): the
# sparse pick learned only from 25-40 robot-minutes on state, and its utd 20 made the image runs learner-bound.
# _gate: _dense with interventions (HIL-SERL's recipe: RLPD on the robot's data with an operator's corrections): the
# scripted expert, acting as a human operator that reads the object pose, takes a robot over for 20 steps when its
# tcp leaves the safe box, it drops the cube or its return stalls for 15 steps (--task_config=operator=gate); the
# policy still sees only the cameras and proprioception, and the evaluations run without the operator.
# EVALS (default 3): how many of a job's last checkpoints get the 40-episode evaluations.
# EXTRA: flags added to every job's training command (--keep_replay in a first call, --keep_replay --resume in a second
# on the same warm machine with RUNS on /tmp).
# _rt: image RLPD peg insertion in real time (--speed=1, whatever SPEED says) with --utd_mode=free (the robots never
# wait for the learner: under the default hold the workers pause whenever the learner is behind the ratio, and a
# paused worker's robot holds its command: 0.54 of steps late at 086aebf); episode/late_fraction in the metrics is
# the share of steps whose action reached a robot after its control period (the robot held its last command), and
# perf/utd the update-to-data ratio the learner reached.
# The image jobs: front + wrist cameras at 64 px, 2 frames each, DrQ's encoder; the critic reads the same images and
# proprioception (no object pose anywhere), or with _asym also the privileged state (the actor its own encoder).
# Five runs at once share the GPU at ~75 env steps/s each, two at ~186 (H100 + 16 cores).
R=$(printf 'sim:franka_emika_panda,%.0s' $(seq 12)); R=${R%,}
RP=$(printf 'sim:franka_emika_panda,sim:universal_robots_ur5e,%.0s' $(seq 6)); RP=${RP%,}
F="--robots=$R --num_workers=8 --eval_envs=4 --eval_every=3000 --speed=${SPEED:-10} --total_steps=${TOTAL:-36000} --config utd=20 --config updates_per_call=64 --config publish_every=64"
P="--dense_reward --task_config=lock_rotation=true --config init_alpha=0.01 --config utd=10"
S="--observation=state"
RLPD_PEG="experiments/rlpd_franka_peg.py $F $P $S --config actor_every=2"
D="--dense_reward --config utd=10 --config actor_every=10"
G="$D --task_config=operator=gate"
I="--task_config=image_size=64 --config encoder_channels=(32,32,32,32) --config encoder_strides=(2,1,1,1) --config feature_dim=50"
export XLA_PYTHON_CLIENT_PREALLOCATE=false
job() {
  local name=$1 s=${1##*_s}; local kind=${name%_s*}; local a
  case $kind in
    rlpd_peg) a="$RLPD_PEG";;
    rlpdflow_peg) a="$RLPD_PEG --algo=rlpd_flow";;
    sac_peg) a="experiments/sac_franka_peg.py $F $P $S";;
    rlpd_pick) a="experiments/rlpd_franka_pick.py $F $S --config actor_every=20";;
    sac_pick) a="experiments/sac_franka_pick.py $F --nodense_reward $S --config actor_hidden=(128,128) --config critic_hidden=(128,128)";;
    sacflow_pick) a="experiments/sacflow_franka_pick.py $F --nodense_reward $S --config actor_hidden=(128,128) --config critic_hidden=(128,128)";;
    rlpd_peg_images) a="experiments/rlpd_franka_peg.py $F $P $I --config actor_every=2";;
    rlpdflow_peg_images) a="experiments/rlpd_franka_peg.py $F $P $I --config actor_every=2 --algo=rlpd_flow";;
    rlpd_pick_images) a="experiments/rlpd_franka_pick.py $F $I --config actor_every=20";;
    rlpd_peg_images_asym) a="experiments/rlpd_franka_peg.py $F $P $I --asymmetric --config actor_every=2";;
    rlpd_pick_images_asym) a="experiments/rlpd_franka_pick.py $F $I --asymmetric --config actor_every=20";;
    rlpd_peg_images_rt) a="experiments/rlpd_franka_peg.py ${F/--speed=${SPEED:-10}/--speed=1} $P $I --config actor_every=2 --utd_mode=free";;
    rlpd_pick_images_pair) a="experiments/rlpd_franka_pick.py ${F/--robots=$R/--robots=$RP} $I --config actor_every=20";;
    rlpd_pick_images_dense) a="experiments/rlpd_franka_pick.py $F $I $D";;
    rlpd_pick_images_gate) a="experiments/rlpd_franka_pick.py $F $I $G";;
    rlpd_pick_images_gate_pair) a="experiments/rlpd_franka_pick.py ${F/--robots=$R/--robots=$RP} $I $G";;
  esac
  local d=${RUNS:-runs}/$name
  timeout ${JOB_TIMEOUT:-540} python3 $a ${EXTRA:-} --seed=$s --logdir=$d > $OUT/$name.log 2>&1; echo "$name exit $?" >> $OUT/$name.log
  python3 bench/compact_metrics.py $d/metrics.jsonl $OUT/$name.jsonl.gz >> $OUT/$name.log 2>&1
  cp $d/summary.json $OUT/${name}_summary.json 2>/dev/null
  local dr=""; case $kind in *peg*|*dense*|*gate*) dr="--task_config=dense_reward=true";; esac
  local arms=franka; case $kind in *_pair) arms="franka ur5e";; esac
  for c in $(ls $d/checkpoints 2>/dev/null | sort -n | tail -${EVALS:-3}); do
    for arm in $arms; do  # in-process robots of that arm; reports of another arm than the Franka's named _<arm>
      local tag=""; [ $arm = franka ] || tag=_$arm
      JAX_PLATFORMS=cpu timeout 120 python3 -m unilab_jax.play --logdir=$d --checkpoint=$c --episodes=40 --seed=1 --task_config='robots=()' --task_config=arm=$arm $dr > $OUT/${name}${tag}_eval40_$c.json 2>> $OUT/$name.log &
    done
  done; wait
}
# DEADLINE (default 560) seconds after this script starts, whatever still runs (a training past JOB_TIMEOUT's share, an
# evaluation) is stopped so that the archive below is written inside a 10-minute call (3 jobs' evaluations ran past it);
# what has not ended 15 s later is killed (at 2d5a972 seven jobs' shutdown ran the call past its 600 s: no archive).
# Each job's three 40-episode evaluations take 60-100 s after its training: a training that runs to JOB_TIMEOUT with
# DEADLINE less than that after it ends with no report (the twelfth session: DEADLINE 400, JOB_TIMEOUT 360). The
# defaults (540, 560) count on TOTAL ending the training first, so this is a warning, not a refusal.
if [ "${DEADLINE:-560}" -lt $(( ${JOB_TIMEOUT:-540} + 100 )) ]; then
  echo "warning: DEADLINE=${DEADLINE:-560} leaves under 100 s for the evaluations of a training that runs to" \
    "JOB_TIMEOUT=${JOB_TIMEOUT:-540}: lower TOTAL or JOB_TIMEOUT if the trainings may run that long" >&2
fi
( sleep "${DEADLINE:-560}"; pkill -TERM -f "unilab_jax.play" ; pkill -TERM -f "experiments/"; sleep 15
  pkill -KILL -f "unilab_jax.play"; pkill -KILL -f "experiments/" ) & watchdog=$!
# GPUS="0 1 2 3": job k runs on GPU GPUS[k mod n] (CUDA_VISIBLE_DEVICES) and, with CORES=C, on cores [kC, (k+1)C) (the
# 4-GPU kind: learner-bound image runs side by side, one GPU each); RUNS: where the runs' logdirs go (default runs/;
# /tmp/... keeps them for a --resume in the next call on the same warm machine).
read -ra gpus <<< "${GPUS:-}"; k=0
for j in "$@"; do
  (
    if [ "${#gpus[@]}" -gt 0 ]; then export CUDA_VISIBLE_DEVICES=${gpus[$((k % ${#gpus[@]}))]}; fi
    if [ -n "${CORES:-}" ]; then taskset -pc "$((k * CORES))-$(((k + 1) * CORES - 1))" $BASHPID > /dev/null; fi
    job "$j"
  ) &
  k=$((k + 1))
done
while sleep 30; do n=$(jobs -pr | grep -vc "^$watchdog$"); [ "$n" = 0 ] && break; for j in "$@"; do tail -c 200 $OUT/$j.log | tr '\n' ' ' | tail -c 110; echo; done; done
wait $(jobs -p | grep -v "^$watchdog$"); kill $watchdog 2>/dev/null
# The evaluations as robot_learning.json records, and everything in one archive (at most 8 files come back from $OUT).
python3 bench/robot_learning.py "$OUT" --out "$OUT/robot_learning.json" --commit "${COMMIT:-unknown}"
tar czf /tmp/franka_runs.tgz -C "$OUT" . && find "$OUT" -mindepth 1 -delete && mv /tmp/franka_runs.tgz "$OUT/"
