#!/usr/bin/env bash
# One SCL decode (m = 6, d = 2, 2 x 256 tanh, Gram-Schmidt, H a): the Rust serving path
# (mapper/benches/decode_latency.rs, per-call percentiles) against PyTorch eager
# (bench/decode_torch.py), in one run, and their ratio. PyTorch is skipped, with a message,
# when `python3 -c 'import torch'` fails.
set -euo pipefail
cd "$(dirname "$0")/.."
echo "machine: $(nproc) CPUs, load average $(cut -d' ' -f1-3 /proc/loadavg)" >&2
rust=$(cargo bench -q -p mapper --bench decode_latency 2>/dev/null | grep '"Avx2Fma"\|"Portable"' | head -1)
echo "rust:    $rust"
if ! python3 -c 'import torch' 2>/dev/null; then
    echo "pytorch: skipped (python3 cannot import torch; pip install torch to compare)"
    exit 0
fi
torch=$(python3 bench/decode_torch.py 2>/dev/null | tail -1)
echo "pytorch: $torch"
python3 - "$rust" "$torch" <<'PY'
import json, sys
r, t = json.loads(sys.argv[1]), json.loads(sys.argv[2])
print(f"ratio rust/pytorch: p50 {r['p50_us'] / t['p50_us']:.3f}  p99 {r['p99_us'] / t['p99_us']:.3f}"
      f"  (rust p50 {r['p50_us']:.2f} us, pytorch p50 {t['p50_us']:.2f} us)")
PY
