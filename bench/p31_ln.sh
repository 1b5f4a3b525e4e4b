#!/usr/bin/env bash
# Issue 31 on the H100 + 16 cores machine: the LayerNorm + ReLU kernels of the bf16 critics, the learner alone.
# First the Pallas kernels' GPU check (the compiled Triton kernels against XLA's programs), then
# bench/learner_update.py rows, bf16, one per variant (xla: XLA's forward and backward; bwd: the Pallas backward;
# fused: the Pallas forward and backward, what "auto" picks on one NVIDIA GPU; flat: fused, and the optimizers over
# one flat parameter vector, flat_optimizer=true; prefix: fused, and the C51 target's O(B K) projection,
# projection=prefix) for each recipe of RECIPES, REPEATS calls each; the last variant of the
# first recipe also traced (trace_summary) and its optimised HLO kept. Under $OUT: p31_ln.tgz with
# lu_<recipe>_<variant>.json, trace_<recipe>_<variant>.json, hlo_<recipe>_<variant>.txt.gz, pytest.txt, setup.txt
# (one archive: a call brings back at most 8 files).
#   COMMIT=$(git rev-parse --short HEAD) bash bench/p31_ln.sh
set -u
RES=/tmp/p31_ln/res; mkdir -p "$RES" "${OUT:=/tmp/p31_out}"
source bench/device_setup.sh > "$RES/setup.txt" 2>&1 || { cat "$RES/setup.txt"; exit 1; }
head -3 "$RES/setup.txt"
python3 -m pytest -q -p no:cacheprovider tests/algos/test_compute_dtype.py -k "pallas or ln_kernels" > "$RES/pytest.txt" 2>&1
tail -2 "$RES/pytest.txt"
RECIPES=${RECIPES:-"fastsac_go1:go1 fastsac_g1:g1"}; VARIANTS=${VARIANTS:-"xla bwd fused"}; REPEATS=${REPEATS:-20}
first=${RECIPES%% *}; last=${VARIANTS##* }
for r in $RECIPES; do
  recipe=${r%%:*}; sizes=${r##*:}
  for v in $VARIANTS; do
    case $v in
      xla) cfg="--config ln_forward=xla --config ln_backward=xla" ;;
      bwd) cfg="--config ln_forward=xla --config ln_backward=pallas" ;;
      fused) cfg="--config ln_forward=pallas --config ln_backward=pallas" ;;
      flat) cfg="--config ln_forward=pallas --config ln_backward=pallas --config flat_optimizer=true" ;;
      prefix) cfg="--config ln_forward=pallas --config ln_backward=pallas --config projection=prefix" ;;
      *) echo "variant must be xla, bwd, fused, flat or prefix"; exit 2 ;;
    esac
    extra=""; flags=""
    if [ "$r" = "$first" ] && [ "$v" = "$last" ]; then
      extra="--profile_dir /tmp/p31_ln/prof"; flags="--xla_dump_to=/tmp/p31_ln/dump --xla_dump_hlo_module_re=jit_update"
    fi
    XLA_FLAGS="$flags" python3 bench/learner_update.py --platforms jax --dtypes bfloat16 --algos fastsac \
      --recipe "experiments/$recipe.py" --sizes "$sizes" --repeats "$REPEATS" $cfg $extra \
      --out "$RES/lu_${recipe}_$v.json" 2>&1 | grep -v Warning | tail -2
  done
done
for d in /tmp/p31_ln/prof/*/; do
  python3 bench/trace_summary.py "$d" --top 40 --out "$RES/trace_${first%%:*}_$last.json" > /tmp/p31_ln/ts.txt
  head -16 /tmp/p31_ln/ts.txt
done
hlo=$(ls /tmp/p31_ln/dump/*jit_update*after_optimizations.txt 2>/dev/null | head -1)
[ -n "$hlo" ] && gzip -c "$hlo" > "$RES/hlo_${first%%:*}_$last.txt.gz"
echo "commit ${COMMIT:-?}" > "$RES/commit.txt"
tar czf "$OUT/p31_ln.tgz" -C "$RES" .
