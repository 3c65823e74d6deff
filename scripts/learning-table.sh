#!/usr/bin/env bash
# Trains PCA, SCL and CAE (with and without the paper's variations) on one data set and prints
# the validation reconstruction MSE of each as a Markdown table (scl eval reconstruction, which
# also writes CSV, a bar chart and summary.md to OUT_DIR/eval).
# The same command works for any data set in the project's CSV layout (train/, val/), e.g. the
# Gen3 lite task sets once they exist:
#
#   scripts/learning-table.sh data/joint-reach [OUT_DIR]
#
# Environment: EPOCHS (200), SEEDS (10) for the networks. Models, loss logs and loss curves
# are left in OUT_DIR (default: target/learning-table/<data set name>); existing ones are
# replaced.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${1:?usage: scripts/learning-table.sh DATA_DIR [OUT_DIR]}
out=${2:-target/learning-table/$(basename "$data")}
EPOCHS=${EPOCHS:-200}
SEEDS=${SEEDS:-10}
cargo build --release -q -p scl --bin scl
scl=target/release/scl
mkdir -p "$out"
net=(--data "$data" --latent-dim 2 --epochs "$EPOCHS" --seeds "$SEEDS" --force)
"$scl" train --kind pca --data "$data" --latent-dim 2 --out "$out/pca.safetensors" --force
"$scl" train --kind scl "${net[@]}" --out "$out/scl.safetensors"
"$scl" train --kind scl "${net[@]}" --no-gram-schmidt --out "$out/scl-no-gs.safetensors"
"$scl" train --kind scl "${net[@]}" --no-lipschitz --out "$out/scl-no-lipschitz.safetensors"
"$scl" train --kind scl "${net[@]}" --encoder projection --out "$out/scl-projection.safetensors"
"$scl" train --kind cae "${net[@]}" --out "$out/cae.safetensors"
# The paper's pouring configuration: proportionality (alpha sampled up to 1.0) and
# reversibility.
"$scl" train --kind cae "${net[@]}" --li-losses proportionality,reversibility \
    --out "$out/cae-li-prop-rev.safetensors"
"$scl" train --kind cae "${net[@]}" --li-losses consistency,proportionality,reversibility \
    --out "$out/cae-li-all.safetensors"
"$scl" eval reconstruction --out "$out/eval" --data "$data" --models \
    "$out"/pca.safetensors "$out"/scl.safetensors "$out"/scl-no-gs.safetensors \
    "$out"/scl-no-lipschitz.safetensors "$out"/scl-projection.safetensors \
    "$out"/cae.safetensors "$out"/cae-li-prop-rev.safetensors "$out"/cae-li-all.safetensors
