#!/usr/bin/env bash
# Builds the Debian package of scl-teleop: /usr/bin/scl (release build), the systemd unit
# scl-graph.service, /etc/scl/graph.toml and /etc/scl/kortex.env (conffiles: an upgrade never
# overwrites a lab's edits), the robot descriptions and the bundled model under /usr/share/scl
# (the binary carries them embedded; these copies are for reading and for config paths), and
# the maintainer scripts that create the `scl` system user in the `input` group.
#
#   packaging/deb/build.sh [--out DIR] [--version VERSION] [--no-build]
#
# Prints the path of the .deb. Needs cargo and dpkg-deb (Debian's dpkg), nothing else.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
out="$root/target/deb"
version=""
build=1
while [ $# -gt 0 ]; do
    case "$1" in
        --out) out="$2"; shift 2 ;;
        --version) version="$2"; shift 2 ;;
        --no-build) build=0; shift ;;
        -h|--help) sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
        *) echo "build.sh: unknown option $1 (see --help)" >&2; exit 2 ;;
    esac
done
command -v dpkg-deb >/dev/null || { echo "build.sh: dpkg-deb not found (apt-get install dpkg)" >&2; exit 1; }
if [ -z "$version" ]; then
    version="$(sed -n 's/^version = "\(.*\)"/\1/p' "$root/Cargo.toml" | head -1)"
fi
target_dir="${CARGO_TARGET_DIR:-$root/target}"
if [ "$build" = 1 ]; then
    (cd "$root" && cargo build --release --locked -p scl --bin scl)
fi
bin="$target_dir/release/scl"
[ -x "$bin" ] || { echo "build.sh: $bin not found (build it, or drop --no-build)" >&2; exit 1; }
arch="$(dpkg --print-architecture)"
stage="$(mktemp -d)"
trap 'rm -rf "$stage"' EXIT
pkg="$stage/scl-teleop"
install -d "$pkg/DEBIAN" "$pkg/usr/bin" "$pkg/etc/scl" "$pkg/lib/systemd/system" \
    "$pkg/usr/share/scl/robots" "$pkg/usr/share/scl/models" "$pkg/usr/share/doc/scl-teleop"
install -m 0755 "$bin" "$pkg/usr/bin/scl"
# Debug information stays in the build tree: the package carries the stripped binary.
strip --strip-debug "$pkg/usr/bin/scl" 2>/dev/null || true
install -m 0644 "$root/packaging/graph.toml" "$pkg/etc/scl/graph.toml"
install -m 0600 "$root/packaging/kortex.env" "$pkg/etc/scl/kortex.env"
install -m 0644 "$root/packaging/scl-graph.service" "$pkg/lib/systemd/system/scl-graph.service"
install -m 0644 "$root"/robots/* "$pkg/usr/share/scl/robots/"
install -m 0644 "$root/models/default.safetensors" "$pkg/usr/share/scl/models/bundled.safetensors"
# The Gen3's bundled model (the binary embeds both; these copies are for reading and replay).
install -m 0644 "$root/models/gen3.safetensors" "$pkg/usr/share/scl/models/gen3.safetensors"
install -m 0644 "$root/README.md" "$root/examples/graph.toml" "$root/docs/network.md" \
  "$pkg/usr/share/doc/scl-teleop/"
for s in postinst prerm postrm; do
    install -m 0755 "$root/packaging/deb/$s" "$pkg/DEBIAN/$s"
done
printf '/etc/scl/graph.toml\n/etc/scl/kortex.env\n' > "$pkg/DEBIAN/conffiles"
size_kb="$(du -sk "$pkg" --exclude=DEBIAN | cut -f1)"
cat > "$pkg/DEBIAN/control" <<CONTROL
Package: scl-teleop
Version: $version
Architecture: $arch
Maintainer: scl-teleop developers <scl-teleop@example.invalid>
Installed-Size: $size_kb
Depends: adduser, libc6
Recommends: systemd
Section: misc
Priority: optional
Homepage: https://example.invalid/scl-teleop
Description: real-time joystick teleoperation of a robot arm through learned maps
 A Kinova Gen3 lite (or its mock) driven from a 2-axis joystick through state-conditioned
 linear maps, as a graph of processes on iceoryx2 shared memory at 40 Hz, with a whole-arm
 safety filter. Installs scl, the scl-graph systemd service (runs as the scl user with
 real-time rights) and /etc/scl/graph.toml.
CONTROL
mkdir -p "$out"
deb="$out/scl-teleop_${version}_${arch}.deb"
dpkg-deb --root-owner-group --build "$pkg" "$deb" >/dev/null
echo "$deb"
