#!/usr/bin/env bash
# CI: builds the Debian package, installs it with dpkg (as root), runs the installed
# `scl up --config /etc/scl/graph.toml` on the mock arm and checks 0 missed ticks, checks the
# installed files, their modes and the `scl` user, verifies the unit with systemd-analyze,
# upgrades to a second build over an edited /etc/scl/graph.toml (the edit must survive), then
# removes and purges the package. The service itself is not started: systemd is not the init
# of CI machines.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
[ "$(id -u)" = 0 ] || { echo "ci-check.sh: needs root (dpkg -i)" >&2; exit 1; }
if ! command -v systemd-analyze >/dev/null; then
    apt-get install -y --no-install-recommends systemd >/dev/null
fi
say() { echo "deb: $*"; }
fail() { echo "deb: FAIL: $*" >&2; exit 1; }
work="$(mktemp -d)"
trap 'dpkg -P scl-teleop >/dev/null 2>&1 || true; rm -rf "$work"' EXIT
base="$(sed -n 's/^version = "\(.*\)"/\1/p' "$root/Cargo.toml" | head -1)"
deb1="$("$root/packaging/deb/build.sh" --out "$work/1" --version "$base")"
deb2="$("$root/packaging/deb/build.sh" --out "$work/2" --version "$base+ci1" --no-build)"
say "built $(basename "$deb1"): $(du -h "$deb1" | cut -f1)"
dpkg-deb --contents "$deb1" | awk '{print $1, $6}'
dpkg -P scl-teleop >/dev/null 2>&1 || true
dpkg -i "$deb1" >/dev/null

# Installed files, modes, owner, user.
check_mode() { # path mode
    local m; m="$(stat -c %a "$1")" || fail "$1 missing"
    [ "$m" = "$2" ] || fail "$1 has mode $m, expected $2"
}
check_mode /usr/bin/scl 755
check_mode /etc/scl/graph.toml 644
check_mode /etc/scl/kortex.env 600
check_mode /lib/systemd/system/scl-graph.service 644
[ "$(stat -c %U /etc/scl/kortex.env)" = root ] || fail "/etc/scl/kortex.env not owned by root"
for f in robots/gen3_lite.urdf robots/gen3_lite_collision.toml models/bundled.safetensors \
    models/gen3.safetensors; do
    [ -f "/usr/share/scl/$f" ] || fail "/usr/share/scl/$f missing"
done
getent passwd scl >/dev/null || fail "no scl user"
id -nG scl | tr ' ' '\n' | grep -qx input || fail "scl is not in the input group"
say "files, modes and the scl user: ok"

# The unit file.
systemd-analyze verify /lib/systemd/system/scl-graph.service
say "systemd-analyze verify: ok"

# The installed binary runs the installed configuration on the mock arm.
/usr/bin/scl doctor --config /etc/scl/graph.toml || fail "scl doctor reported a fail"
out="$(SCL_PREFIX="cideb$$" /usr/bin/scl up --config /etc/scl/graph.toml --for 5s --json)"
echo "$out"
python3 - "$out" <<'PY'
import json, sys
s = json.loads(sys.argv[1])
assert s["failure"] is None, s["failure"]
assert s["ticks"] >= 150, f"only {s['ticks']} ticks in 5 s"
assert s["missed"] == 0, f"{s['missed']} missed ticks"
PY
say "installed scl up: 0 missed ticks"

# An upgrade keeps the lab's edit of the conffile.
echo "# edited by the lab" >> /etc/scl/graph.toml
dpkg -i "$deb2" >/dev/null </dev/null
tail -1 /etc/scl/graph.toml | grep -qx "# edited by the lab" || fail "the upgrade overwrote /etc/scl/graph.toml"
[ "$(dpkg-query -W -f '${Version}' scl-teleop)" = "$base+ci1" ] || fail "upgrade not installed"
say "upgrade kept the edited /etc/scl/graph.toml"

# Remove keeps the configuration; purge removes it.
dpkg -r scl-teleop >/dev/null
[ ! -e /usr/bin/scl ] || fail "/usr/bin/scl left after remove"
[ -f /etc/scl/graph.toml ] || fail "remove deleted the configuration"
dpkg -P scl-teleop >/dev/null
[ ! -e /etc/scl/graph.toml ] || fail "purge left /etc/scl/graph.toml"
say "remove and purge: ok"
ls /dev/shm | grep -q "^scl_cideb$$" && fail "shared memory left by the installed run"
say "all package checks passed"
