#!/usr/bin/env python3
"""Checks that moving the README's reference material into docs/ lost nothing (issue 28).

Every backticked token, every line of a code block and every number with its unit in the
README of git revision REV (default f28851b, before the move) must appear in README.md or a
docs/*.md page of the working tree (whitespace-normalised). Tokens changed on purpose are
listed in CHANGED with the reason. Exit code 1 on anything missing.

    scripts/check-docs-moved.py [REV]
"""
import pathlib
import re
import subprocess
import sys

# Old token -> why it is not found verbatim (each is replaced by a fuller, true form).
CHANGED = {
    "scl up [--config FILE] [--for 60s] [--json] [--model FILE] [--script circle|step] "
    "[--joystick SOURCE]": "now lists `constant` (a script `scl up` accepts) and --record, --live",
    "scl bench latency [--for 60s] [--rt | --rt-only fifo|mlock|pin|dma-latency] [--load N] "
    "[--rate-hz N] [--transport iceoryx2|uds|both] [--json] [--out DIR]": "now lists --live",
    "scl joystick | mapper --model FILE | safety | bridge --robot mock": "the README listed the "
    "per-process commands twice; docs/cli.md keeps the fuller form once",
}

# Renames made after the move (old spelling -> new): a token found in its new spelling counts.
RENAMED = {"-p services": "-p scl", "services/doctor": "cli/src/doctor"}


def found(token, text):
    if token in text:
        return True
    for a, b in RENAMED.items():
        token = token.replace(a, b)
    return token in text


rev = sys.argv[1] if len(sys.argv) > 1 else "f28851b"
root = pathlib.Path(__file__).resolve().parent.parent
old = subprocess.run(["git", "-C", str(root), "show", f"{rev}:README.md"],
                     check=True, capture_output=True, text=True).stdout
pages = [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def norm(s):
    return re.sub(r"\s+", " ", s).strip()


new = norm("\n".join(p.read_text() for p in pages))
prose = re.sub(r"```.*?```", "", old, flags=re.S)
ticks = {norm(t) for t in re.findall(r"`([^`\n]+(?:\n[^`\n]+)?)`", prose)}
code = {norm(line) for block in re.findall(r"```[a-z]*\n(.*?)```", old, flags=re.S)
        for line in block.splitlines() if line.strip()}
nums = {norm(m) for m in re.findall(r"\d[\d.,]*\s?(?:%|[A-Za-zµ°]+)", old)}

failed = False
for name, items in [("backticked tokens", ticks), ("code-block lines", code),
                    ("numbers with units", nums)]:
    missing = sorted(t for t in items if not found(t, new) and t not in CHANGED)
    changed = sorted(t for t in items if not found(t, new) and t in CHANGED)
    print(f"{name}: {len(items)}, missing {len(missing)}, changed on purpose {len(changed)}")
    for t in missing:
        print(f"  missing: {t}")
    failed |= bool(missing)
print(f"pages checked: {', '.join(str(p.relative_to(root)) for p in pages)}")
sys.exit(1 if failed else 0)
