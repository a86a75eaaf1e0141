#!/usr/bin/env bash
# The surrogate stage's GPU checks, in one short run on a machine with CUDA and torch
# (docs/surrogate.md, "Speed"): the surrogate tests (with the CUDA test of every model kind),
# CUDA training of f-coulomb and f-memory against the same training on the CPU, and the
# batched rollout bench at 10^4 and 10^5 rollouts. Needs the sweep's datasets in DATA.
#
#   bash bench/gpu_check.sh            # DATA=data OUT=out/gpu_check
#
# On a machine whose python3 has torch but not this project: PIP_INSTALL=1 installs it
# (editable, no dependencies, no network; h5netcdf and tomli-w must already be importable).
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${DATA:-data}
OUT=${OUT:-out/gpu_check}
PY=${PY:-python3}
EPOCHS=${EPOCHS:-60}
mkdir -p "$OUT"
export PYTHONUNBUFFERED=1
if [ -n "${PIP_INSTALL:-}" ]; then
    $PY -m pip install -q --no-deps --no-build-isolation --no-index -e . 2>&1 | tail -2
fi
$PY - <<'EOF'
import torch
assert torch.cuda.is_available(), "no CUDA device: these are the GPU checks"
print("torch", torch.__version__, "on", torch.cuda.get_device_name(), flush=True)
EOF
for f in "$DATA"/C{1,2,3}.nc; do test -f "$f" || { echo "missing $f (make sweep)"; exit 2; }; done

echo "== surrogate tests (the CUDA test runs for every model kind)"
$PY -m pytest -q -p no:cacheprovider tests/surrogate -m "not fem" -k "not ladder" 2>&1 | tee "$OUT/pytest.log" | tail -15

echo "== training on C1 (val C2), CUDA against CPU, $EPOCHS epochs"
for kind in f-coulomb f-memory; do
    for dev in cuda cpu; do
        start=$(date +%s%N)
        $PY -m deapull.workflows train --data "$DATA" --train C1 --val C2 --model $kind --epochs $EPOCHS \
            --device $dev --out "$OUT/train_${kind}_$dev" > "$OUT/train_${kind}_$dev.log" 2>&1
        echo "$kind $dev: $(( ($(date +%s%N) - start) / 1000000 )) ms; $(tail -1 "$OUT/train_${kind}_$dev.log")"
    done
done

echo "== batched rollouts (the bench trains each model 20 epochs on C1/C2; the cost does not depend on the weights)"
# (the LSTM re-reads its window each step: 10^5 of its rollouts take ~40 s each, so it is timed at 10^4 only)
for n in 10000 100000; do
    kinds=f,f-coulomb,f-memory,nn; [ $n -le 10000 ] && kinds=$kinds,lstm
    $PY bench/bench_surrogate.py --data "$DATA" --kinds $kinds --batch $n --repeats 5 --out "$OUT/bench_b$n.json" \
        > "$OUT/bench_b$n.log" 2>&1
    grep -A12 "^1 s rollout" "$OUT/bench_b$n.log"
done
