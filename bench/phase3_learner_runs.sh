#!/usr/bin/env bash
# The device commands behind bench/results/{h100,h100x2,h200x2}/phase3/ (issue 31's "before" profile): run on the GPU
# machine from the checkout's root, results under $OUT (one .tgz + the log, as the device tool brings back).
#
#   bash bench/phase3_learner_runs.sh single   # 1 GPU: learner_update rows + traces per recipe, HLO of FastSAC Go1
#   bash bench/phase3_learner_runs.sh scale    # 2 GPUs: scale_out learner, 1 vs 2 devices, traces + HLO
#   bash bench/phase3_learner_runs.sh scale_dtype   # 2 GPUs: the same with one dtype on both sides
#   bash bench/phase3_learner_runs.sh rollouts      # 2 GPUs + 32 cores: Ray, 1 vs 2 local nodes of 16 CPUs
# (Ray travels pruned, as .rayx/ray_pruned.tar.xz + jsonschema's wheels, in the scale_dtype call; rollouts needs
# the bundle of bench/device_bundle.sh: carry .devr/whl and .devr/unitree_go1.tar.xz.)
#
# Everything bf16 ("auto" on a GPU) and with --xla_gpu_enable_triton_gemm=false, as the experiments run
# (unilab_jax/cli.py sets it; the benches do not). P3_EXTRA: more learner_update args (a quick CPU check:
# P3_EXTRA="--config batch_size=256 --repeats 2").
set -u
OUT=${OUT:-/tmp/phase3_out}
rm -rf /tmp/p3; mkdir -p "$OUT" /tmp/p3
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
base_flags="--xla_gpu_enable_triton_gemm=false"
log=$OUT/log.txt
exec > >(tee -a "$log") 2>&1
nproc; nvidia-smi -L; nvidia-smi --query-gpu=name,memory.total,clocks.max.sm,driver_version --format=csv
nvidia-smi topo -m 2>/dev/null || true
python3 -c "import jax; print('jax', jax.__version__, jax.devices())"
[ -f bench/learner_update.py ] || { echo "run from the checkout root"; exit 1; }

lu() {  # name, extra learner_update args...
  local name=$1; shift
  echo "== $name: $*"
  XLA_FLAGS="$base_flags ${HLO:-}" python3 bench/learner_update.py --platforms jax --dtypes bfloat16 --repeats 10 \
    --profile_dir /tmp/p3/prof_$name --out /tmp/p3/lu_$name.json "$@" ${P3_EXTRA:-}
  for d in /tmp/p3/prof_$name/*/; do
    python3 bench/trace_summary.py "$d" --top 60 --out /tmp/p3/trace_${name}.json > /tmp/p3/ts.txt; head -12 /tmp/p3/ts.txt
    cp "$(ls -t $(find "$d" -name perfetto_trace.json.gz) | head -1)" /tmp/p3/perfetto_$name.json.gz
  done
}

case "${1:-single}" in
single)
  HLO="--xla_dump_to=/tmp/p3/hlo_fastsac_go1 --xla_dump_hlo_as_text --xla_dump_hlo_module_re=jit_update" \
    lu fastsac_go1 --algos fastsac --recipe experiments/fastsac_go1.py --sizes go1
  lu flashsac_go2 --algos flashsac --recipe experiments/flashsac_go2.py --sizes go2
  lu fastsac_g1 --algos fastsac --recipe experiments/fastsac_g1.py --sizes g1
  lu fastsac_go1_u32 --algos fastsac --recipe experiments/fastsac_go1.py --sizes go1 --config updates_per_call=32
  # ablation (diagnosis only, not a recipe): what the critic's LayerNorm costs end to end
  lu fastsac_go1_noln --algos fastsac --recipe experiments/fastsac_go1.py --sizes go1 --config critic_layer_norm=false
  ;;
scale)
  hlo="--xla_dump_to=/tmp/p3/hlo_scale --xla_dump_hlo_as_text --xla_dump_hlo_module_re=jit_+update"
  echo "== scale_out learner 1 2 x 8192 (traced)"
  XLA_FLAGS="$base_flags $hlo" python3 bench/scale_out.py learner --devices 1 2 --batch_per_device 8192 \
    --profile_dir /tmp/p3/prof_scale --out /tmp/p3/scale_out_learner_8192.json
  for n in 1 2; do
    python3 bench/trace_summary.py /tmp/p3/prof_scale/devices_$n --top 60 --out /tmp/p3/trace_scale_d$n.json \
      > /tmp/p3/ts.txt; head -12 /tmp/p3/ts.txt
    cp "$(ls -t $(find /tmp/p3/prof_scale/devices_$n -name perfetto_trace.json.gz) | head -1)" \
      /tmp/p3/perfetto_scale_d$n.json.gz
  done
  echo "== scale_out learner 1 2 x 4096 (2 x 4096: the 1 x 8192 global batch split)"
  XLA_FLAGS="$base_flags" python3 bench/scale_out.py learner --devices 1 2 --batch_per_device 4096 \
    --out /tmp/p3/scale_out_learner_4096.json
  echo "== scale_out learner 1 x 16384 (the 2 x 8192 global batch on one GPU)"
  XLA_FLAGS="$base_flags" python3 bench/scale_out.py learner --devices 1 --batch_per_device 16384 \
    --out /tmp/p3/scale_out_learner_16384.json
  ;;
scale_dtype)  # the same comparison with both sides in one dtype (float32; bf16, which 97357f3 measured through a
  # bench-only flag, --dp_in_compute_dtype: since the sharding fix the data-parallel path traces the learner's dtype)
  unpack=""; [ -f .rayx/ray_pruned.tar.xz ] && (mkdir -p /tmp/rayx && tar xJf .rayx/ray_pruned.tar.xz -C /tmp/rayx \
    && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/rayx .rayx/*.whl && echo ray unpacked) &
  unpack=$!
  echo "== scale_out learner 1 2 x 8192, float32 on both"
  XLA_FLAGS="$base_flags" python3 bench/scale_out.py learner --devices 1 2 --batch_per_device 8192 \
    --compute_dtype float32 --out /tmp/p3/scale_out_learner_8192_f32.json
  echo "== scale_out learner 1 2 x 8192, bf16 on both (traced)"
  XLA_FLAGS="$base_flags" python3 bench/scale_out.py learner --devices 1 2 --batch_per_device 8192 \
    --profile_dir /tmp/p3/prof_scale --out /tmp/p3/scale_out_learner_8192_bf16dp.json
  for n in 1 2; do
    python3 bench/trace_summary.py /tmp/p3/prof_scale/devices_$n --top 60 --out /tmp/p3/trace_scale_bf16dp_d$n.json \
      > /tmp/p3/ts.txt; head -12 /tmp/p3/ts.txt
    cp "$(ls -t $(find /tmp/p3/prof_scale/devices_$n -name perfetto_trace.json.gz) | head -1)" \
      /tmp/p3/perfetto_scale_bf16dp_d$n.json.gz
  done
  echo "== scale_out learner 2 x 4096, bf16: the 1 x 8192 batch split"
  XLA_FLAGS="$base_flags" python3 bench/scale_out.py learner --devices 2 --batch_per_device 4096 \
    --out /tmp/p3/scale_out_learner_4096_bf16dp.json
  wait $unpack
  ;;
ray_unpack)  # Ray alone (when no scale_dtype call came just before on the same machine)
  mkdir -p /tmp/rayx && tar xJf .rayx/ray_pruned.tar.xz -C /tmp/rayx \
    && python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/rayx .rayx/*.whl && echo ray unpacked
  ;;
rollouts)  # Ray: one local node of 16 CPUs vs two (same host), Go1, after scale_dtype/ray_unpack put Ray in /tmp/rayx
  ROBOTS=unitree_go1 source bench/device_setup.sh
  # 127.0.0.1 stays loopback (else Ray resolves it to the host's address, where the local nodes do not listen)
  export PYTHONPATH=$PYTHONPATH:/tmp/rayx RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0
  python3 -c "import ray; print('ray', ray.__version__)" || exit 1
  for nodes in 1 2; do
    echo "== rollouts, $nodes local Ray node(s) of 16 CPUs"
    timeout 170 python3 bench/scale_out.py rollouts --local_nodes $nodes --cpus_per_node 16 --task go1_joystick_flat \
      --num_workers 15 --workers_per_host 16 --envs_per_worker 64 --replay_capacity 32768 --warmup 8 --seconds 15 \
      --out /tmp/p3/scale_out_rollouts_go1_${nodes}node.json || break
  done
  ;;
esac
rm -rf /tmp/p3/prof_* 2>/dev/null
find /tmp/p3 -path '*hlo*' -type f ! -name '*optimizations.txt' -delete 2>/dev/null
find /tmp/p3 -mindepth 1 -type d -empty -delete; rm -f /tmp/p3/ts.txt
tar czf "$OUT/phase3_${1:-single}.tgz" -C /tmp/p3 .
ls -la "$OUT"
