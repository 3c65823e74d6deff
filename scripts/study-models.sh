#!/usr/bin/env bash
# Trains the models the example studies (examples/study/) serve, which the repository ships in
# models/study/ (learning/tests/study_models.rs checks they are this script's output): for each of the paper's
# three Gen3 lite tasks, demonstrations (`scl demos`, the paper's counts) and SCL, CAE and
# PCA fitted on them at the paper's settings (d = 2, 2 x 256, 200 epochs, best of 10 seeds;
# SCL with Gram-Schmidt and L = 1), into models/study/<kind>-<task>.safetensors.
#
#   scripts/study-models.sh          # the paper's settings (11 minutes on 2 cores, release)
#   QUICK=1 scripts/study-models.sh  # 1 seed, 20 epochs: a dry run's models (minutes)
#
# The check `scl train` prints after training on a paper's task is left out here
# (`--no-check`); run it with `scl eval capability MODEL --task T`.
#
# Existing files are kept (delete them to retrain); training is deterministic per seed.
# The loss logs (*.loss.csv, *.loss.png) are written beside the models.
set -euo pipefail
cd "$(dirname "$0")/.."
cargo build --release -q -p scl --bin scl
scl=target/release/scl
mkdir -p models/study data/study
extra=()
if [ "${QUICK:-0}" = 1 ]; then extra=(--seeds 1 --epochs 20); fi
for task in table-cleaning pick-and-place pouring; do
    data="data/study/$task"
    [ -e "$data" ] || "$scl" demos --task "$task" --seed 1 --out "$data"
    for kind in pca scl cae; do
        out="models/study/$kind-$task.safetensors"
        if [ -e "$out" ]; then echo "kept $out"; continue; fi
        if [ "$kind" = pca ]; then
            "$scl" train --kind pca --data "$data" --out "$out" --no-check
        else
            "$scl" train --kind "$kind" --data "$data" --out "$out" --no-check "${extra[@]}"
        fi
    done
done
echo "models in models/study/; check a study with: scl study plan examples/study/study1.toml"
