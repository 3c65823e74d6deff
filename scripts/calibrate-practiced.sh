#!/usr/bin/env bash
# Calibrates the practiced simulated operator on the one condition with published human
# figures: mode switching (examples/study/calibration.toml, condition A). For each value of
# `[simulation.practiced] mode_slip` it simulates the participants, then prints a table (paper
# against simulated: presses per pouring attempt, successes per task) and the value to make
# the default: the one whose mean presses per pouring attempt come closest to the paper's
# 17.55 among those that succeed in at least 2/3 of pouring attempts and in more than half of
# the table-cleaning and pick-and-place attempts.
#
#   scripts/calibrate-practiced.sh [OUT] [PARTICIPANTS] [VALUES...]
#   scripts/calibrate-practiced.sh target/calibration 13 0 0.1 0.2 0.3 0.4 0.5   # the defaults
#
# A value whose run is complete in OUT is not run again (delete OUT/slip-V to rerun it), so an
# interrupted calibration goes on where it stopped. The table is also written to OUT/table.md.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-target/calibration}
participants=${2:-13}
shift $(( $# > 2 ? 2 : $# ))
values=("$@")
[ ${#values[@]} -gt 0 ] || values=(0 0.1 0.2 0.3 0.4 0.5)
cargo build --release -q -p scl --bin scl
scl=target/release/scl
mkdir -p "$out"
for v in "${values[@]}"; do
    dir="$out/slip-$v"
    if [ -e "$dir/done" ]; then echo "kept $dir"; continue; fi
    rm -rf "$dir"
    mkdir -p "$dir"
    study="$dir/calibration.toml"
    # The study file with the value under [simulation.practiced] (models are specs, not paths).
    sed "s/^operator = \"practiced\"$/operator = \"practiced\"\n[simulation.practiced]\nmode_slip = $v/" \
        examples/study/calibration.toml > "$study"
    grep -q "^mode_slip = $v$" "$study"
    "$scl" study simulate "$study" --participants "$participants" --seed 1 --condition A \
        --out "$dir/sim"
    touch "$dir/done"
done
python3 - "$out" "${values[@]}" <<'PY'
import csv, glob, statistics, sys
out, values = sys.argv[1], sys.argv[2:]
PAPER_MEAN, PAPER_SD = 17.55, 3.91
rows = []
for v in values:
    trials = []
    for f in sorted(glob.glob(f"{out}/slip-{v}/sim/P*/trials.csv")):
        with open(f) as fh:
            trials += list(csv.DictReader(fh))
    def task(name):
        return [t for t in trials if t["task"] == name]
    def ok(ts):
        return sum(t["outcome"] == "success" for t in ts), len(ts)
    pour = task("pouring")
    presses = [int(t["mode_switches"]) for t in pour]
    mean = statistics.mean(presses) if presses else float("nan")
    sd = statistics.stdev(presses) if len(presses) > 1 else float("nan")
    p_ok, p_n = ok(pour)
    t_ok, t_n = ok(task("table-cleaning"))
    k_ok, k_n = ok(task("pick-and-place"))
    good = p_n > 0 and 3 * p_ok >= 2 * p_n and 2 * t_ok > t_n and 2 * k_ok > k_n
    rows.append((v, mean, sd, p_ok, p_n, t_ok, t_n, k_ok, k_n, good))
lines = [
    "| mode_slip | presses per pouring attempt | pouring | table cleaning | pick-and-place | meets the success rule |",
    "|---|---|---|---|---|---|",
    f"| paper's participants | {PAPER_MEAN} ± {PAPER_SD} | mostly completed | | | |",
]
for v, mean, sd, p_ok, p_n, t_ok, t_n, k_ok, k_n, good in rows:
    lines.append(f"| {v} | {mean:.2f} ± {sd:.2f} | {p_ok}/{p_n} | {t_ok}/{t_n} | {k_ok}/{k_n} | {'yes' if good else 'no'} |")
candidates = [r for r in rows if r[-1]]
if candidates:
    best = min(candidates, key=lambda r: abs(r[1] - PAPER_MEAN))
    lines.append("")
    lines.append(f"Calibrated: mode_slip = {best[0]} ({best[1]:.2f} presses per pouring attempt against the paper's {PAPER_MEAN}).")
else:
    lines.append("")
    lines.append("No value meets the success rule: the practiced operator cannot be calibrated on these values.")
text = "\n".join(lines)
print(text)
with open(f"{out}/table.md", "w") as fh:
    fh.write(text + "\n")
PY
