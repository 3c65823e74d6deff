#!/usr/bin/env bash
# Regenerates the files the project ships that its own code produced:
#   data/joint-reach/          joint-space reaching demonstrations (scl demos, seed 1)
#   models/default.safetensors the bundled model fitted on DATA (scl train)
# The old files are moved aside (to *.old) rather than overwritten.
#
# The bundled model is PCA on the joint-reach set for now. To bundle SCL once the pick-and-
# place demonstrations exist, change the one line below to
#   BUNDLED=(--kind scl --data data/pick-and-place)
# (scl's defaults are the paper's: d = 2, 2 x 256 tanh, Gram-Schmidt, L = 1, 200 epochs,
# best of 10 seeds).
set -euo pipefail
cd "$(dirname "$0")/.."
BUNDLED=(--kind pca --data data/joint-reach)
cargo build --release -q -p services --bin scl
scl=target/release/scl
if [ -e data/joint-reach ]; then rm -rf data/joint-reach.old; mv data/joint-reach data/joint-reach.old; fi
"$scl" demos --task joint-reach --seed 1 --train 6 --val 2 --out data/joint-reach
if [ -e models/default.safetensors ]; then mv models/default.safetensors models/default.safetensors.old; fi
for f in models/default.loss.csv models/default.loss.png; do
    if [ -e "$f" ]; then mv "$f" "$f.old"; fi
done
"$scl" train "${BUNDLED[@]}" --latent-dim 2 --out models/default.safetensors
echo "regenerated; rebuild scl to embed the new model (cargo build --release)"
