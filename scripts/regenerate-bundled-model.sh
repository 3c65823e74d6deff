#!/usr/bin/env bash
# Regenerates the files the project ships that its own code produced:
#   data/joint-reach/          joint-space reaching demonstrations (scl demos, seed 1); the
#                              tests fit PCA models with known directions on them
#   data/pick-and-place/       the paper's pick-and-place task (scl demos, seed 1; 2001 training
#                              tuples as in the paper)
#   models/default.safetensors the bundled model: SCL trained on data/pick-and-place with the
#                              paper's defaults (d = 2, 2 x 256 tanh, Gram-Schmidt, L = 1, 200
#                              epochs, best of 10 seeds) and a speed scale of 0.6 rad/s at full
#                              deflection (about the Gen3 lite's default joint speeds)
# Old files are moved aside (to *.old) rather than overwritten. Everything is deterministic:
# the same commit regenerates the same bytes.
set -euo pipefail
cd "$(dirname "$0")/.."
BUNDLED=(--kind scl --data data/pick-and-place --speed-scale 0.6)
cargo build --release -q -p scl --bin scl
scl=target/release/scl
for d in data/joint-reach data/pick-and-place; do
    if [ -e "$d" ]; then rm -rf "$d.old"; mv "$d" "$d.old"; fi
done
"$scl" demos --task joint-reach --seed 1 --train 6 --val 2 --out data/joint-reach
"$scl" demos --task pick-and-place --seed 1 --out data/pick-and-place
for f in models/default.safetensors models/default.loss.csv models/default.loss.png; do
    if [ -e "$f" ]; then mv "$f" "$f.old"; fi
done
"$scl" train "${BUNDLED[@]}" --latent-dim 2 --out models/default.safetensors
echo "regenerated; rebuild scl to embed the new model (cargo build --release)"
