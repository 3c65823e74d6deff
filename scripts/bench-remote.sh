#!/usr/bin/env bash
# The remote operator's figures (docs/network.md): a graph whose gateway takes the joystick,
# and `scl joystick --remote` driving it with the circle script for DURATION, over loopback
# and over a veth pair between two network namespaces (needs root and iproute2). Prints, per
# link, the operator's round trip (a sample sent -> the gateway's acknowledgement: p50 / p99 /
# max), the gateway's CPU time per tick (every thread, Zenoh's included), and the graph's
# summary (ticks, missed, end-to-end latency from the gateway's arrival stamp).
#
#   scripts/bench-remote.sh [SCL_BINARY] [DURATION_S]
#
# Then over the veth pair with 1 ms and 5 ms of added delay each way. This machine's kernel
# has no netem (CONFIG_NET_SCH_NETEM is not set), so the delay is a relay in the operator's
# namespace (scripts/delay-relay.py, standard-library Python) that holds every byte for the
# delay in each direction: the round trip grows by twice the delay.
set -euo pipefail
scl=${1:-target/release/scl}
secs=${2:-20}
dir=$(mktemp -d)
trap 'ip netns del sclbr-$$ 2>/dev/null || true; ip netns del sclbo-$$ 2>/dev/null || true; rm -rf "$dir"' EXIT
printf 'operator:bench-only\n' > "$dir/creds"
chmod 600 "$dir/creds"

run() { # name, listen address, robot-side prefix command, operator-side prefix command,
        # [the operator's endpoint, default the listen address's]
  local name=$1 addr=$2 rns=$3 ons=$4 endpoint=${5:-tcp/$2:7447}
  local prefix="benchremote$$${name}"
  cat > "$dir/$name.toml" <<EOF
[network]
enabled = true
accept_joystick = true
listen = ["tcp/$addr:7447"]
credentials = "$dir/creds"
EOF
  SCL_LOG=info $rns "$scl" up --prefix "$prefix" --config "$dir/$name.toml" \
    --for "$((secs + 4))s" --json > "$dir/$name.json" 2> "$dir/$name.up.log" &
  local up=$!
  sleep 2
  SCL_LOG=info timeout --signal=INT "$secs" $ons "$scl" joystick --prefix "$prefix" \
    --config "$dir/$name.toml" --remote "$endpoint" --credentials "$dir/creds" \
    --source script --script circle 2> "$dir/$name.op.log" || true
  wait "$up"
  echo "== $name"
  grep -h "round trip to the gateway" "$dir/$name.op.log" | sed 's/.*INFO //'
  grep -h "gateway CPU time" "$dir/$name.up.log" | sed 's/.*INFO //'
  python3 -c 'import json,sys; s=json.load(open(sys.argv[1])); print("graph: ticks", s["ticks"], "missed", s["missed"], "held_up", s["held_up"], "e2e (us)", s["latency_us"])' "$dir/$name.json"
}

run loopback 127.0.0.1 "" ""

ip netns add "sclbr-$$"
ip netns add "sclbo-$$"
ip link add "vbr$$" type veth peer name "vbo$$"
ip link set "vbr$$" netns "sclbr-$$"
ip link set "vbo$$" netns "sclbo-$$"
ip -n "sclbr-$$" addr add 10.214.0.1/30 dev "vbr$$"
ip -n "sclbo-$$" addr add 10.214.0.2/30 dev "vbo$$"
for n in "sclbr-$$:vbr$$" "sclbo-$$:vbo$$"; do
  ip -n "${n%%:*}" link set lo up
  ip -n "${n%%:*}" link set "${n#*:}" up
done
run veth 10.214.0.1 "ip netns exec sclbr-$$" "ip netns exec sclbo-$$"
here=$(cd "$(dirname "$0")" && pwd)
for ms in 1 5; do
  ip netns exec "sclbo-$$" python3 "$here/delay-relay.py" 127.0.0.1:7448 10.214.0.1:7447 "$ms" &
  relay=$!
  sleep 0.5
  run "veth-${ms}ms" 10.214.0.1 "ip netns exec sclbr-$$" "ip netns exec sclbo-$$" tcp/127.0.0.1:7448
  kill "$relay" 2>/dev/null || true
  wait "$relay" 2>/dev/null || true
done
