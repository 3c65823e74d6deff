#!/usr/bin/env bash
# Soak test (issue 41): run the whole graph (`scl up --for DURATION`) at a given rate with the
# recorder, the live Foxglove server and the network gateway attached, a Foxglove client
# (`scl live --client`) on the server and a remote observer (`scl record --remote`) on the
# gateway, sample every process's resident memory and open file descriptors and the graph's
# files in /dev/shm every INTERVAL, then check that none of them grows, that both clients were
# served throughout, and that the graph's own recording replays bit for bit. See --help and
# docs/benchmarks.md ("Soak"). CI runs it for 5 minutes (.ci/run).
set -euo pipefail

usage() {
  cat <<'EOF'
Usage: scripts/soak.sh [OPTIONS]

Runs `scl up --for DURATION --record FILE --json --live` (the mock arm, the scripted circle
joystick, the recorder, the live Foxglove server and the network gateway) under a prefix of its
own, with two clients attached for the whole run: a Foxglove client on the live server
(`scl live --client`, subscribed to every channel, as Foxglove is) and a remote observer on the
gateway (`scl record --remote`, through Zenoh on loopback, recording everything). Samples every
process (the clients too) every INTERVAL, and checks:
  rss      each process's VmRSS at most RSS_SLACK above its value at the first sample
  fds      each process's open file descriptors (the least of 3 looks) as at the first sample
  shm      the graph's files in /dev/shm (scl_<prefix>_*) as many as at the first sample
  procs    the same processes (pids) at every sample: none died or was restarted
  up       `scl up` exited 0 (no child died for good)
  clean    no file of the prefix left in /dev/shm after the run
  replay   `scl replay --json` of the recording: every tick identical, exit 0
  foxglove the Foxglove client received frames in every interval and never lost the server
  remote   the remote observer was served throughout: its file grew in every interval, it
           wrote messages and exited 0 at the end
Missed ticks (the bridge's own counters, `scl up --json`'s `missed` and `held_up`) are
reported, not checked: on a busy machine the scheduler decides them. So is the replay of the
remote recording: the gateway's queue drops the newest messages when the network side is
behind (counted), and a recording that lacks a robot state or a joystick sample cannot be
replayed bit for bit from there on (`scl replay` counts the ticks it diverged on a lost
joystick sample, `diverged_on_lost_input`).
The first sample is taken one INTERVAL after the start (the graph warmed up); no sample is
taken in the last 5 s (the graph stopping).

Options:
  --for DURATION     how long the graph runs (ms, s, m, h as `scl up --for`; default 1h)
  --rate HZ          the graph's rate, [graph] rate_hz (default 1000, the most it takes)
  --interval SEC     seconds between samples (default 60)
  --rss-slack KIB    allowed RSS growth per process after the first sample (default 2048)
  --out DIR          output directory (default target/soak/<UTC time>)
  --prefix NAME      graph prefix (default soak<pid>; must not be in use)
  --scl PATH         the scl binary (default: <cargo target dir>/release/scl, built if missing)
  --no-live          do not attach `scl live` (the Foxglove server, on 127.0.0.1, a free port)
                     nor its Foxglove client
  --no-gateway       do not start the network gateway ([network] enabled, Zenoh on
                     127.0.0.1, a free port) nor the remote observer
  --no-clients       start the live server and the gateway, but no client of either
  --keep-recording   keep the MCAP files (default: removed when every check passes; each
                     takes about 0.7 MB per second at 1 kHz)
  -h, --help         this help

Writes into DIR: graph.toml, samples.csv (time_s,process,pid,rss_kib,fds,shm_files),
clients.csv (time_s,foxglove_frames,foxglove_connects,remote_mcap_bytes), up.json (the run's
summary), up.log, replay.json, replay.log, foxglove.jsonl (the client's report each second),
foxglove.log, remote.json (the remote recorder's report), remote.log, remote-replay.json,
remote-replay.log, report.txt.
Exit status: 0 when every check passes, 1 when one fails, 2 on a usage or setup error.
EOF
}

die() {
  echo "soak: $*" >&2
  exit 2
}

duration=1h
rate=1000
interval=60
rss_slack=2048
out=""
prefix="soak$$"
scl=""
live=1
gateway=1
keep_recording=0
clients=1
while [ $# -gt 0 ]; do
  case "$1" in
  --for) duration=${2:?--for needs a value}; shift 2 ;;
  --rate) rate=${2:?--rate needs a value}; shift 2 ;;
  --interval) interval=${2:?--interval needs a value}; shift 2 ;;
  --rss-slack) rss_slack=${2:?--rss-slack needs a value}; shift 2 ;;
  --out) out=${2:?--out needs a value}; shift 2 ;;
  --prefix) prefix=${2:?--prefix needs a value}; shift 2 ;;
  --scl) scl=${2:?--scl needs a value}; shift 2 ;;
  --no-live) live=0; shift ;;
  --no-gateway) gateway=0; shift ;;
  --keep-recording) keep_recording=1; shift ;;
  --no-clients) clients=0; shift ;;
  -h | --help) usage; exit 0 ;;
  *) echo "soak: unknown option '$1'" >&2; usage >&2; exit 2 ;;
  esac
done

# The duration in whole seconds (rounded up), for the sampling schedule; `scl up` parses the
# original text itself.
duration_s=$(awk -v d="$duration" 'BEGIN {
  if (match(d, /^[0-9]+(\.[0-9]+)?/) == 0) exit 1
  v = substr(d, 1, RLENGTH); u = substr(d, RLENGTH + 1)
  if (u == "ms") v /= 1000; else if (u == "" || u == "s") v = v;
  else if (u == "m" || u == "min") v *= 60; else if (u == "h") v *= 3600; else exit 1
  s = int(v); if (s < v) s++; print s }') ||
  die "--for '$duration' is not a duration (e.g. 300s, 5m, 1h)"
[[ "$rate" =~ ^[0-9]+(\.[0-9]+)?$ ]] || die "--rate '$rate' is not a number of Hz"
[[ "$interval" =~ ^[1-9][0-9]*$ ]] || die "--interval '$interval' is not a whole number of seconds"
[[ "$rss_slack" =~ ^[0-9]+$ ]] || die "--rss-slack '$rss_slack' is not a number of KiB"
[[ "$prefix" =~ ^[A-Za-z0-9_-]+$ ]] || die "--prefix '$prefix': letters, digits, _ and - only"
# A first sample one interval in and at least one more before the last 5 s.
if [ "$duration_s" -lt $((2 * interval + 5)) ]; then
  die "--for $duration is too short for --interval $interval: it needs at least $((2 * interval + 5)) s for two samples"
fi

# Paths given relative to where the script was started from, before it moves to the
# repository's root (where cargo finds the workspace).
here=$PWD
case "$out" in "" | /*) ;; *) out="$here/$out" ;; esac
case "$scl" in "" | /*) ;; *) scl="$here/$scl" ;; esac
cd "$(dirname "$0")/.."
target_dir=${CARGO_TARGET_DIR:-$(cargo metadata --format-version 1 --no-deps 2>/dev/null |
  python3 -c 'import json, sys; print(json.load(sys.stdin)["target_directory"])' 2>/dev/null ||
  echo target)}
if [ -z "$scl" ]; then
  scl="$target_dir/release/scl"
  if [ ! -x "$scl" ]; then
    echo "soak: building $scl (cargo build --release -p scl)" >&2
    cargo build --release -q -p scl --bin scl
  fi
fi
[ -x "$scl" ] || die "no scl binary at '$scl' (build it: cargo build --release -p scl, or pass --scl)"

if [ -z "$out" ]; then
  out="$target_dir/soak/$(date -u +%Y%m%dT%H%M%SZ)"
fi
mkdir -p "$out" || die "cannot create the output directory '$out'"
out=$(cd "$out" && pwd)

shm_prefix="scl_${prefix}_"
shm_count() {
  # Only names, so a file removed between the listing and the count does not matter.
  find /dev/shm -maxdepth 1 -name "${shm_prefix}*" 2>/dev/null | wc -l
}
if [ "$(shm_count)" -ne 0 ]; then
  die "/dev/shm already holds files of prefix '$prefix' (${shm_prefix}*): another graph of that prefix runs, or one left them; choose another --prefix"
fi

# A free loopback port, picked by the kernel (a race with another program is possible but
# harmless: the server then fails to start and the run says so).
free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

# The graph's configuration: the built-in defaults (examples/graph.toml) with the rate and
# the prefix, and the gateway's section when asked for.
cfg="$out/graph.toml"
{
  echo "# Written by scripts/soak.sh."
  echo "[graph]"
  echo "rate_hz = $rate"
  echo "prefix = \"$prefix\""
  if [ "$gateway" = 1 ]; then
    zport=$(free_port)
    echo "[network]"
    echo "enabled = true"
    echo "listen = [\"tcp/127.0.0.1:$zport\"]"
  fi
} >"$cfg"

recording="$out/run.mcap"
remote_recording="$out/remote.mcap"
csv="$out/samples.csv"
report="$out/report.txt"
echo "time_s,process,pid,rss_kib,fds,shm_files" >"$csv"
clients_csv="$out/clients.csv"
echo "time_s,foxglove_frames,foxglove_connects,remote_mcap_bytes" >"$clients_csv"

up_args=(--prefix "$prefix" --config "$cfg" up --for "$duration" --record "$recording" --json)
if [ "$live" = 1 ]; then
  lport=$(free_port)
  up_args+=(--live "127.0.0.1:$lport")
fi
echo "soak: $scl ${up_args[*]}" >&2
echo "soak: output in $out; samples every ${interval} s over ${duration_s} s" >&2

# `scl up` in its own process group, so that stopping it here (Ctrl-C, an error) reaches
# it and it stops its children in order (bridge first).
set -m
"$scl" "${up_args[@]}" >"$out/up.json" 2>"$out/up.log" &
up_pid=$!
set +m

# The clients, each in its own process group too; they wait for their server themselves
# (the Foxglove client up to 30 s, the remote observer until the gateway answers).
client_pid=""
remote_pid=""
if [ "$clients" = 1 ] && [ "$live" = 1 ]; then
  set -m
  "$scl" live --client "127.0.0.1:$lport" --json >"$out/foxglove.jsonl" 2>"$out/foxglove.log" &
  client_pid=$!
  set +m
fi
if [ "$clients" = 1 ] && [ "$gateway" = 1 ]; then
  # The remote observer connects once: wait (up to 30 s) until the gateway listens.
  for _ in $(seq 300); do
    (exec 3<>"/dev/tcp/127.0.0.1/$zport") 2>/dev/null && break
    kill -0 "$up_pid" 2>/dev/null || break
    sleep 0.1
  done
  set -m
  "$scl" --prefix "$prefix" --config "$cfg" record --remote "tcp/127.0.0.1:$zport" \
    --out "$remote_recording" --json >"$out/remote.json" 2>"$out/remote.log" &
  remote_pid=$!
  set +m
fi
# SIGINT to each client; one still running 60 s later (the remote observer closes a file of
# gigabytes) is killed, and its status is then not 0, so its check fails instead of the soak
# hanging.
stop_clients() {
  local p
  for p in $client_pid $remote_pid; do
    kill -INT "$p" 2>/dev/null || true
  done
  for _ in $(seq 600); do
    local alive=0
    for p in $client_pid $remote_pid; do
      if kill -0 "$p" 2>/dev/null; then alive=1; fi
    done
    [ "$alive" = 1 ] || break
    sleep 0.1
  done
  for p in $client_pid $remote_pid; do
    kill -KILL "$p" 2>/dev/null || true
  done
  client_status=0
  remote_status=0
  [ -z "$client_pid" ] || wait "$client_pid" 2>/dev/null || client_status=$?
  [ -z "$remote_pid" ] || wait "$remote_pid" 2>/dev/null || remote_status=$?
}
cleanup() {
  if kill -0 "$up_pid" 2>/dev/null; then
    kill -TERM "$up_pid" 2>/dev/null || true
    wait "$up_pid" 2>/dev/null || true
  fi
  stop_clients
}
trap cleanup EXIT
trap 'echo "soak: interrupted" >&2; exit 130' INT TERM

# Every process of the graph: `scl up` and its descendants (its children are `scl` itself
# run with a subcommand; `scl live`, the recorder and the gateway too).
descendants() {
  local p
  for p in $(pgrep -P "$1" 2>/dev/null || true); do
    echo "$p"
    descendants "$p"
  done
}
# A process's name in the CSV: its subcommand and, for a mapper, its id (the supervisor
# starts a second mapper for a live swap).
proc_name() {
  local args role="" id="" prev=""
  mapfile -d '' -t args <"/proc/$1/cmdline" 2>/dev/null || return 1
  for a in "${args[@]:1}"; do
    case "$a" in
    up) [ -n "$role" ] || role=supervisor ;;
    joystick | mapper | safety | bridge | record | live | gateway)
      [ -n "$role" ] || role=$a ;;
    --client) role=foxglove-client ;;
    --remote) role=remote-observer ;;
    esac
    [ "$prev" != "--id" ] || id=$a
    prev=$a
  done
  [ -n "$role" ] || role=$(cat "/proc/$1/comm" 2>/dev/null || echo unknown)
  echo "${role}${id:+-$id}"
}

# A process's open descriptors: the least of three looks 20 ms apart, so that one opened for
# a moment (a directory listed while the supervisor looks for dead nodes) is not taken for a
# leak; a leaked one stays in all three.
fd_count() {
  local n least=""
  for _ in 1 2 3; do
    n=$(find "/proc/$1/fd" -mindepth 1 -maxdepth 1 2>/dev/null | wc -l)
    if [ -z "$least" ] || [ "$n" -lt "$least" ]; then least=$n; fi
    sleep 0.02
  done
  echo "$least"
}

t0=$(date +%s)
next=$interval
while kill -0 "$up_pid" 2>/dev/null; do
  now=$(($(date +%s) - t0))
  if [ "$now" -ge "$next" ]; then
    if [ "$now" -le $((duration_s - 5)) ]; then
      shm=$(shm_count)
      for pid in "$up_pid" $(descendants "$up_pid") $client_pid $remote_pid; do
        name=$(proc_name "$pid") || continue
        rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null) || continue
        fds=$(fd_count "$pid")
        echo "$now,$name,$pid,${rss:-0},$fds,$shm" >>"$csv"
      done
      # What the clients got so far: the Foxglove client's newest report, the remote
      # recording's size (it grows by chunks, about one a second).
      fx=$(tail -n 1 "$out/foxglove.jsonl" 2>/dev/null | jq -r '"\(.frames),\(.connects)"' 2>/dev/null) || fx=","
      echo "$now,${fx:-,},$(stat -c %s "$remote_recording" 2>/dev/null || echo)" >>"$clients_csv"
      echo "soak: t=${now}s sampled ($(grep -c "^$now," "$csv") processes, $shm shm files)" >&2
    fi
    next=$((next + interval))
  fi
  sleep 1
done
up_status=0
wait "$up_pid" || up_status=$?
trap - EXIT
# The graph has stopped: the clients go next (the remote observer closes its file).
stop_clients

# The graph's processes all release their files on a clean stop; give them a moment.
left=0
for _ in $(seq 50); do
  left=$(shm_count)
  [ "$left" -eq 0 ] && break
  sleep 0.1
done

replay_status=0
"$scl" replay "$recording" --json >"$out/replay.json" 2>"$out/replay.log" || replay_status=$?
remote_replay_status=0
if [ -n "$remote_pid" ]; then
  "$scl" replay "$remote_recording" --json >"$out/remote-replay.json" 2>"$out/remote-replay.log" ||
    remote_replay_status=$?
fi
# One check line for a replay: replay_check NAME STATUS JSON LOG
replay_check() {
  if [ "$2" = 0 ] && jq -e '.diverged == 0 and .ticks == .identical and .ticks > 0' "$3" >/dev/null 2>&1; then
    check "$1" 1 "$(jq -r '"\(.ticks) ticks replayed, \(.identical) identical, \(.diverged) diverged"' "$3")"
  else
    check "$1" 0 "scl replay exited $2: $(jq -c '{ticks, identical, diverged, first_divergence}' \
      "$3" 2>/dev/null || tail -n 3 "$4")"
  fi
}

# The checks, each one line `PASS|FAIL name: detail`.
fail=0
check() { # check NAME OK DETAIL
  if [ "$2" = 1 ]; then echo "PASS $1: $3"; else echo "FAIL $1: $3"; fail=1; fi
}
{
  echo "soak: $duration at $rate Hz, prefix $prefix, $(date -u +%Y-%m-%dT%H:%M:%SZ), $(nproc) CPUs"
  samples=$(tail -n +2 "$csv" | cut -d, -f1 | sort -un | wc -l)
  if [ "$samples" -lt 2 ]; then
    check samples 0 "$samples sample(s) taken; the checks need two (scl up stopped early? see $out/up.log)"
  fi
  # Per process: the first sample's values and the worst later ones.
  tail -n +2 "$csv" | awk -F, -v slack="$rss_slack" '
    !($2 in first_rss) { order[n++] = $2; first_rss[$2] = $4; first_fds[$2] = $5; pid[$2] = $3
                         max_rss[$2] = $4; min_fds[$2] = $5; max_fds[$2] = $5 }
    { if ($4 > max_rss[$2]) max_rss[$2] = $4
      if ($5 < min_fds[$2]) min_fds[$2] = $5
      if ($5 > max_fds[$2]) max_fds[$2] = $5
      if ($3 != pid[$2]) moved[$2] = moved[$2] " " $3 }
    END {
      for (i = 0; i < n; i++) {
        p = order[i]; g = max_rss[p] - first_rss[p]
        printf "%s %s rss %d KiB at first sample, max +%d KiB (allowed %d)\n",
          (g <= slack ? "PASS" : "FAIL"), "rss[" p "]:", first_rss[p], g, slack
        printf "%s %s %d at first sample, %d..%d after\n",
          (min_fds[p] == first_fds[p] && max_fds[p] == first_fds[p] ? "PASS" : "FAIL"),
          "fds[" p "]:", first_fds[p], min_fds[p], max_fds[p]
        if (p in moved) printf "FAIL procs[%s]: pid %s, later%s (restarted)\n", p, pid[p], moved[p]
      }
    }' >"$out/per-process.txt"
  cat "$out/per-process.txt"
  grep -q '^FAIL' "$out/per-process.txt" && fail=1
  # The process set: every sample has the same names.
  sets=$(tail -n +2 "$csv" | awk -F, '{ s[$1] = s[$1] " " $2 } END { for (t in s) print s[t] }' |
    sort -u | wc -l)
  check procs "$([ "$sets" -le 1 ] && echo 1 || echo 0)" \
    "$(tail -n +2 "$csv" | cut -d, -f2 | sort -u | tr '\n' ' ')at every sample ($sets distinct set(s))"
  read -r shm_min shm_max shm_first < <(tail -n +2 "$csv" | awk -F, '
    NR == 1 { f = $6; lo = $6; hi = $6 } { if ($6 < lo) lo = $6; if ($6 > hi) hi = $6 }
    END { print lo + 0, hi + 0, f + 0 }')
  check shm "$([ "$shm_min" = "$shm_first" ] && [ "$shm_max" = "$shm_first" ] && echo 1 || echo 0)" \
    "$shm_first files ${shm_prefix}* at first sample, $shm_min..$shm_max over the run"
  check up "$([ "$up_status" = 0 ] && echo 1 || echo 0)" "scl up exited $up_status$(
    [ "$up_status" = 0 ] || echo " ($(tail -n 1 "$out/up.log"))")"
  check clean "$([ "$left" = 0 ] && echo 1 || echo 0)" "$left file(s) ${shm_prefix}* left in /dev/shm after the run"
  replay_check replay "$replay_status" "$out/replay.json" "$out/replay.log"
  if [ -n "$client_pid" ]; then
    # Frames in every interval between samples (none stalled), one connection all along,
    # and the client exited cleanly at the end.
    read -r stalls last_frames connects < <(tail -n +2 "$clients_csv" | awk -F, '
      { if (NR > 1 && $2 + 0 <= prev) s++; prev = $2 + 0; c = $3 }
      END { print s + 0, prev + 0, (c == "" ? 0 : c) }')
    final=$(tail -n 1 "$out/foxglove.jsonl" 2>/dev/null)
    check foxglove "$([ "$stalls" = 0 ] && [ "$connects" = 1 ] && [ "$client_status" = 0 ] &&
      [ "$last_frames" -gt 0 ] && echo 1 || echo 0)" \
      "$(echo "$final" | jq -r '"\(.frames) frames on \(.channels) channels in \(.t_s | round) s"' 2>/dev/null || echo "no report"), $connects connection(s), $stalls interval(s) without a frame, exit $client_status"
  fi
  if [ -n "$remote_pid" ]; then
    # Served throughout: the file grew between every two samples (a chunk a second), the
    # recorder wrote messages and stopped cleanly.
    read -r rstalls rbytes < <(tail -n +2 "$clients_csv" | awk -F, '
      { b = $4 + 0; if (NR > 1 && b <= prev) s++; prev = b } END { print s + 0, prev + 0 }')
    written=$(jq -r '.written' "$out/remote.json" 2>/dev/null || echo 0)
    lost=$(jq -r '"\(.dropped) dropped, \(.robot_state_gaps) robot states missing"' "$out/remote.json" 2>/dev/null || echo "no report")
    check remote "$([ "$rstalls" = 0 ] && [ "$remote_status" = 0 ] && [ "${written:-0}" -gt 0 ] &&
      [ "$rbytes" -gt 0 ] && echo 1 || echo 0)" \
      "${written:-0} messages written, $rstalls interval(s) without growth, exit $remote_status; lost on the way: $lost"
    echo "remote replay (reported): $(jq -r '"\(.ticks) ticks, \(.identical) identical, \(.diverged) diverged (\(.diverged_on_lost_input) on a lost joystick sample)"' \
      "$out/remote-replay.json" 2>/dev/null || echo "scl replay exited $remote_replay_status")"
  fi
  if jq -e '.ticks' "$out/up.json" >/dev/null 2>&1; then
    jq -r '"missed ticks: \(.missed) of \(.ticks) (\(.held_up) held up by the machine, \(.missed - .held_up) the graph'"'"'s own); e2e latency p50 / p99 / max \(.latency_us.p50 | round) / \(.latency_us.p99 | round) / \(.latency_us.max | round) µs; restarts \(.restarts)"' "$out/up.json"
  else
    echo "missed ticks: unknown (no summary from scl up; see $out/up.log)"
  fi
  echo "recording: $(du -h "$recording" 2>/dev/null | cut -f1) ($recording)"
  [ -z "$remote_pid" ] || echo "remote recording: $(du -h "$remote_recording" 2>/dev/null | cut -f1) (exit $remote_status)"
  echo "samples: $csv"
} | tee "$report"
grep -q '^FAIL' "$report" && fail=1

if [ "$fail" = 0 ] && [ "$keep_recording" = 0 ]; then
  rm -f "$recording" "$remote_recording"
fi
# Files of the prefix still there (a failed stop) would only take memory: they are ours.
[ "$left" = 0 ] || find /dev/shm -maxdepth 1 -name "${shm_prefix}*" -delete 2>/dev/null || true
if [ "$fail" = 0 ]; then
  echo "soak: PASS" | tee -a "$report"
else
  echo "soak: FAIL (see $report)" | tee -a "$report"
  exit 1
fi
