#!/usr/bin/env python3
"""Non-test Rust functions over a length, longest first (issue 39: long functions).

Lists every function with a body (free function, method, trait default method, nested
function) in the `src/` of the workspace members (read from the root Cargo.toml, as
`scripts/count-lines.py` does) that is longer than `--over` lines. A function's length runs
from the line of its `fn` keyword to the line of its closing brace; the doc comments and
attributes above it are not counted. Test code is left out as `scripts/count-lines.py` leaves
it out: a file stops at a line that is exactly `#[cfg(test)]` (the project keeps its test
modules last), and `src/**/tests.rs` files are skipped. Items marked `#[cfg(test)]` or
`#[test]` elsewhere are skipped too.

Braces are matched on the source with its comments, string literals (raw and byte strings
included) and char literals blanked out, so a brace inside them does not count.

Usage: scripts/long-functions.py [--over N] [--max-over-100 K] [--max-over-150 K] [--root DIR]

Prints the table (length, name, path:line) and the counts over 100 and 150 lines; exits 1
when a `--max-over-*` limit is exceeded.
"""
import argparse
import pathlib
import re
import sys
import tomllib


def blank(text):
    """`text` with comments, strings and char literals replaced by spaces (newlines kept)."""
    out = list(text)
    n = len(text)
    i = 0

    def wipe(a, b):
        for k in range(a, min(b, n)):
            if out[k] != "\n":
                out[k] = " "

    while i < n:
        c = text[i]
        prev = text[i - 1] if i > 0 else ""
        if c == "/" and text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            wipe(i, j)
            i = j
        elif c == "/" and text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            wipe(i, j)
            i = j
        elif c in "rb" and not (prev.isalnum() or prev == "_") and (
            m := re.match(r'(?:br|rb|r)(#*)"', text[i : i + 260])
        ):
            close = '"' + m.group(1)
            j = text.find(close, i + m.end())
            j = n if j < 0 else j + len(close)
            wipe(i, j)
            i = j
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            wipe(i, j + 1)
            i = j + 1
        elif c == "'":
            # A char literal ('a', '\n', '\u{1F600}', '{') or a lifetime / label ('a).
            if i + 1 < n and text[i + 1] == "\\":
                j = text.find("'", i + 2 + (1 if text[i + 2 : i + 3] == "'" else 0))
                j = n if j < 0 else j
                wipe(i, j + 1)
                i = j + 1
            elif i + 2 < n and text[i + 2] == "'":
                wipe(i, i + 3)
                i += 3
            else:
                i += 1
        else:
            i += 1
    return "".join(out)


FN = re.compile(r"(?<![\w$])fn\s+(r#)?([A-Za-z_]\w*)")
IMPL = re.compile(r"(?<!\w)impl\b")
TRAIT = re.compile(r"(?<!\w)trait\s+([A-Za-z_]\w*)")
MOD = re.compile(r"(?<!\w)mod\s+([A-Za-z_]\w*)\s*$")
TEST_ATTR = re.compile(r"#\[\s*(?:cfg\s*\(\s*test\s*\)|test)\s*\]")


def impl_name(header):
    """The type an `impl` block is for: `impl<T> Trait for Foo<T> where ..` gives `Foo`."""
    h = header[IMPL.search(header).end() :]
    h = re.split(r"\bwhere\b", h)[0]
    # Drop the impl's own generics, then take the type after `for` if there is one.
    h = h.strip()
    if h.startswith("<"):
        depth = 0
        for k, ch in enumerate(h):
            depth += {"<": 1, ">": -1}.get(ch, 0)
            if depth == 0:
                h = h[k + 1 :]
                break
    parts = re.split(r"\bfor\b", h)
    ty = parts[-1].strip()
    ty = re.sub(r"<.*", "", ty).strip()
    return ty.split("::")[-1] or "?"


def functions(path, text):
    """Yield (first line, last line, qualified name in the file) for each fn with a body."""
    src = blank(text)
    stack = []  # (kind, name, start line, is test)
    header_start = 0
    line = 1
    for i, c in enumerate(src):
        if c == "\n":
            line += 1
        elif c == "{":
            header = src[header_start:i]
            test = bool(TEST_ATTR.search(header)) or any(s[3] for s in stack)
            # A header that opens an item: the text since the last `;`, `{` or `}`.
            m = FN.search(header)
            if m and "(" in header[m.end() :]:
                fn_line = line - header[m.start() :].count("\n")
                stack.append(("fn", m.group(2), fn_line, test))
            elif IMPL.search(header) and not re.search(r"[=(]", header[: IMPL.search(header).start()]):
                stack.append(("impl", impl_name(header), line, test))
            elif m2 := TRAIT.search(header):
                stack.append(("trait", m2.group(1), line, test))
            elif m3 := MOD.search(header):
                stack.append(("mod", m3.group(1), line, test))
            else:
                stack.append(("block", "", line, test))
            header_start = i + 1
        elif c == "}":
            if stack:
                kind, name, start, test = stack.pop()
                if kind == "fn" and not test:
                    scope = [s[1] for s in stack if s[0] in ("impl", "trait", "mod", "fn")]
                    yield start, line, "::".join(scope + [name])
            header_start = i + 1
        elif c == ";":
            header_start = i + 1


def module_of(crate, src_dir, f):
    """`crate::a::b` for `src/a/b.rs` (or `src/a/b/mod.rs`); `crate` for lib.rs / main.rs."""
    parts = list(f.relative_to(src_dir).with_suffix("").parts)
    if parts and parts[-1] in ("lib", "main", "mod"):
        parts = parts[:-1]
    if parts and parts[0] == "bin":
        parts = parts[1:]
    return "::".join([crate] + parts)


def collect(root):
    """Every non-test function of the workspace: (lines, name, path, first line)."""
    members = tomllib.loads((root / "Cargo.toml").read_text())["workspace"]["members"]
    rows = []
    for m in members:
        src = root / m / "src"
        crate = tomllib.loads((root / m / "Cargo.toml").read_text())["package"]["name"]
        crate = crate.replace("-", "_")
        for f in sorted(src.rglob("*.rs")):
            # Another member's sources (a crate nested in this one's folder) are not this crate's.
            if any((p / "Cargo.toml").exists() for p in f.parents if p != root / m and (root / m) in p.parents):
                continue
            if f.name == "tests.rs":
                continue
            kept = []
            for text_line in f.read_text().splitlines():
                if text_line.strip() == "#[cfg(test)]":
                    break
                kept.append(text_line)
            module = module_of(crate, src, f)
            for start, end, name in functions(f, "\n".join(kept) + "\n"):
                rows.append((end - start + 1, f"{module}::{name}", str(f.relative_to(root)), start))
    rows.sort(key=lambda r: (-r[0], r[1]))
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--over", type=int, default=100, help="list functions longer than N lines")
    ap.add_argument("--max-over-100", type=int, help="fail if more functions are over 100 lines")
    ap.add_argument("--max-over-150", type=int, help="fail if more functions are over 150 lines")
    ap.add_argument("--root", default=".", help="the workspace directory")
    args = ap.parse_args()
    rows = collect(pathlib.Path(args.root))
    print(f"{'lines':>5}  {'function':<60} where")
    for n, name, path, start in rows:
        if n > args.over:
            print(f"{n:>5}  {name:<60} {path}:{start}")
    over100 = sum(1 for r in rows if r[0] > 100)
    over150 = sum(1 for r in rows if r[0] > 150)
    print(f"{len(rows)} functions; {over100} over 100 lines, {over150} over 150 lines")
    failed = False
    if args.max_over_100 is not None and over100 > args.max_over_100:
        print(f"error: {over100} functions over 100 lines (at most {args.max_over_100})", file=sys.stderr)
        failed = True
    if args.max_over_150 is not None and over150 > args.max_over_150:
        print(f"error: {over150} functions over 150 lines (at most {args.max_over_150})", file=sys.stderr)
        failed = True
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
