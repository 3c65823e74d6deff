#!/usr/bin/env bash
# Training time of an SCL model of the paper's size (m = 6, d = 2, encoder and decoder 2 x 256
# tanh, Gram-Schmidt, L = 1 projection, Adam lr 1e-3, batch 256, EPOCHS epochs) on about 5400
# tuples, `scl train` against the same model in PyTorch (bench/train_torch.py), in one run:
#
#   1. one seed, one thread each;
#   2. SEEDS seeds using both cores: scl trains them in parallel, one thread per seed;
#      PyTorch runs as two processes of one thread, each training half of the seeds.
#
# Times are the training loops only (data loading excluded), as each program reports it
# (scl: the model header's training.settings.train_seconds). Usage:
#   bench/compare-training.sh [DATA_DIR]      (default: generates joint-reach data, seed 1)
# Environment: EPOCHS (200), SEEDS (10), KIND (scl).
set -euo pipefail
cd "$(dirname "$0")/.."
EPOCHS=${EPOCHS:-200}
SEEDS=${SEEDS:-10}
KIND=${KIND:-scl}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cargo build --release -q -p scl --bin scl
scl=target/release/scl
data=${1:-}
if [ -z "$data" ]; then
    data=$work/data
    "$scl" demos --task joint-reach --seed 1 --train 19 --val 4 --out "$data" 2>/dev/null
fi
have_torch=1
python3 -c 'import torch' 2>/dev/null || have_torch=0
echo "machine: $(nproc) CPUs, load average $(cut -d' ' -f1-3 /proc/loadavg); data $data; $KIND, $EPOCHS epochs"

header() { # model file -> "train_seconds validation_loss"
    python3 - "$1" <<'PY'
import json, struct, sys
b = open(sys.argv[1], "rb").read()
n = struct.unpack("<Q", b[:8])[0]
h = json.loads(json.loads(b[8:8 + n])["__metadata__"]["scl"])
print(h["training"]["settings"]["train_seconds"], h["training"]["validation_loss"])
PY
}

run_scl() { # seeds threads -> "seconds val"
    "$scl" train --kind "$KIND" --data "$data" --epochs "$EPOCHS" --seeds "$1" --threads "$2" \
        --out "$work/m.safetensors" --force >/dev/null 2>&1
    header "$work/m.safetensors"
}

torch_one() { # seeds offset threads -> json
    python3 bench/train_torch.py --data "$data" --kind "$KIND" --epochs "$EPOCHS" \
        --seeds "$1" --seed-offset "$2" --threads "$3" 2>/dev/null | tail -1
}

read -r s1 v1 < <(run_scl 1 1)
echo "1 seed, 1 thread:   scl     $(printf '%7.1f' "$s1") s  val MSE $v1"
if [ $have_torch = 1 ]; then
    t1=$(torch_one 1 0 1)
    ts1=$(python3 -c 'import json,sys; print(json.loads(sys.argv[1])["seconds"])' "$t1")
    tv1=$(python3 -c 'import json,sys; print(json.loads(sys.argv[1])["val_loss"])' "$t1")
    echo "                    pytorch $(printf '%7.1f' "$ts1") s  val MSE $tv1"
    python3 -c 'import sys; print(f"                    ratio scl/pytorch {float(sys.argv[1]) / float(sys.argv[2]):.3f}")' "$s1" "$ts1"
else
    echo "                    pytorch skipped (python3 cannot import torch)"
fi

read -r sn vn < <(run_scl "$SEEDS" 0)
echo "$SEEDS seeds, 2 cores: scl     $(printf '%7.1f' "$sn") s  best val MSE $vn (one thread per seed)"
if [ $have_torch = 1 ]; then
    half=$((SEEDS / 2))
    start=$(date +%s.%N)
    torch_one "$half" 0 1 > "$work/a.json" &
    torch_one $((SEEDS - half)) "$half" 1 > "$work/b.json" &
    wait
    end=$(date +%s.%N)
    python3 - "$work/a.json" "$work/b.json" "$start" "$end" "$sn" <<'PY'
import json, sys
a, b = (json.load(open(p)) for p in sys.argv[1:3])
wall = float(sys.argv[4]) - float(sys.argv[3])
loops = max(a["seconds"], b["seconds"])
print(f"                    pytorch {loops:7.1f} s  best val MSE {min(a['val_loss'], b['val_loss'])}"
      f" (two 1-thread processes; wall {wall:.1f} s with start-up)")
print(f"                    ratio scl/pytorch {float(sys.argv[5]) / loops:.3f}")
PY
fi
