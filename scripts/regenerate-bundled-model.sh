#!/usr/bin/env bash
# Regenerates the files the project ships that its own code produced, for one robot profile
# (default gen3_lite):
#
#   scripts/regenerate-bundled-model.sh            the Gen3 lite:
#     data/joint-reach/          joint-space reaching demonstrations (scl demos, seed 1); the
#                                tests fit PCA models with known directions on them
#     data/pick-and-place/       the paper's pick-and-place task (scl demos, seed 1: the
#                                paper's six demonstrations, 5291 training tuples at the arm's
#                                accelerations, docs/demos.md)
#     models/default.safetensors the Gen3 lite's bundled model: SCL trained on
#                                data/pick-and-place with the paper's defaults (d = 2, 2 x 256
#                                tanh, Gram-Schmidt, L = 1, 200 epochs, best of 10 seeds) and a
#                                speed scale of 0.6 rad/s at full deflection (about the Gen3
#                                lite's default joint speeds)
#
#   scripts/regenerate-bundled-model.sh gen3       the 7-joint Gen3:
#     data/gen3-pick-and-place/  pick-and-place on the Gen3 (scl demos --robot gen3, seed 1;
#                                the paper's six demonstrations, 2657 training tuples, the
#                                scene moved into the Gen3's workspace)
#     models/gen3.safetensors    the Gen3's bundled model: SCL as above but 2 x 128 tanh (a
#                                quarter of the weights, 156 KB; the same validation loss on
#                                these data), speed scale 0.6 rad/s (about the Gen3's default
#                                joint speeds, 0.5-0.6 rad/s)
#
# The profile embeds its model (kinematics::ProfileSpec::bundled_model): rebuild scl after.
# Old files are moved aside (to *.old) rather than overwritten. Everything is deterministic:
# the same commit regenerates the same bytes. SCL_BIN=path uses that scl instead of building a
# release one (the weights do not depend on the build: the same IEEE operations either way).
set -euo pipefail
cd "$(dirname "$0")/.."
robot=${1:-gen3_lite}
if [ -n "${SCL_BIN:-}" ]; then
    scl=$SCL_BIN
else
    cargo build --release -q -p scl --bin scl
    scl=target/release/scl
fi
case "$robot" in
gen3_lite)
    DATA=(data/joint-reach data/pick-and-place)
    MODEL=models/default.safetensors
    ;;
gen3)
    DATA=(data/gen3-pick-and-place)
    MODEL=models/gen3.safetensors
    ;;
*)
    echo "unknown robot profile '$robot' (gen3_lite, gen3)" >&2
    exit 2
    ;;
esac
for d in "${DATA[@]}"; do
    if [ -e "$d" ]; then rm -rf "$d.old"; mv "$d" "$d.old"; fi
done
for f in "$MODEL" "${MODEL%.safetensors}.loss.csv" "${MODEL%.safetensors}.loss.png"; do
    if [ -e "$f" ]; then mv "$f" "$f.old"; fi
done
case "$robot" in
gen3_lite)
    "$scl" demos --task joint-reach --seed 1 --train 6 --val 2 --out data/joint-reach
    "$scl" demos --task pick-and-place --seed 1 --out data/pick-and-place
    "$scl" train --kind scl --data data/pick-and-place --speed-scale 0.6 --latent-dim 2 \
        --out "$MODEL"
    ;;
gen3)
    "$scl" demos --robot gen3 --task pick-and-place --seed 1 --out data/gen3-pick-and-place
    "$scl" train --kind scl --data data/gen3-pick-and-place --speed-scale 0.6 --latent-dim 2 \
        --hidden 128,128 --out "$MODEL"
    ;;
esac
echo "regenerated; rebuild scl to embed the new model"
