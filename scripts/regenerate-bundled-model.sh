#!/usr/bin/env bash
# Regenerates the files the project ships that its own code produced:
#   data/joint-reach/          joint-space reaching demonstrations (scl demos, seed 1)
#   models/default.safetensors the bundled PCA model fitted on them (scl train)
# The old files are moved aside (to *.old) rather than overwritten.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p services --bin scl
scl=target/release/scl
if [ -e data/joint-reach ]; then rm -rf data/joint-reach.old; mv data/joint-reach data/joint-reach.old; fi
"$scl" demos --task joint-reach --seed 1 --train 6 --val 2 --out data/joint-reach
if [ -e models/default.safetensors ]; then mv models/default.safetensors models/default.safetensors.old; fi
"$scl" train --kind pca --data data/joint-reach --latent-dim 2 --out models/default.safetensors
echo "regenerated; rebuild scl to embed the new model (cargo build --release)"
