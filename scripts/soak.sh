#!/bin/bash
# A long run of the whole mapping stack on the simulator: omni-sim drives its tour LAPS times
# live on the bus (firmware base in the loop) while the supervisor runs odom_mapper, rbpf_mapper,
# pose_graph_mapper, octomap_builder and map_fusion, as the demo does but without idle exits.
# Every 20 s it samples each process's resident memory and CPU time; at the end it stops the
# supervisor (the mappers write their maps) and prints, per process, the memory after the first
# lap and at the end, the growth per lap and the CPU used, then each trajectory's ATE against
# the simulator's truth and each map's error against its truth map.
#
# usage: scripts/soak.sh [--laps N] [--speed X] [--walkers N] [--out DIR]
#   --laps N   tours of the built-in world (default 10; one is 240 s of simulated time)
#   --speed X  times real time (default 2.5: ten laps in about 16 minutes)
#   --walkers N  people walking through the floor (omni-sim --walkers; default 0)
#   --out DIR  where everything goes (default out/soak): supervisor.log, sim.log, rss.txt
#              (unix time, process, RSS kB, CPU ticks), the maps and trajectories
# Runs in a private network namespace (root or user namespaces), so nothing leaves the machine.
set -euo pipefail
ROOT="$(cd "$(dirname "$(readlink -f "${BASH_SOURCE[0]}")")/.." && pwd)"
BUILD="${OMNI_BUILD_DIR:-$ROOT/build}"
LAPS=10 SPEED=2.5 WALKERS=0 OUT="$ROOT/out/soak"
while [ $# -gt 0 ]; do
  case "$1" in
    --laps) LAPS="${2:?--laps needs a value}"; shift 2 ;;
    --speed) SPEED="${2:?--speed needs a value}"; shift 2 ;;
    --walkers) WALKERS="${2:?--walkers needs a value}"; shift 2 ;;
    --out) OUT="${2:?--out needs a value}"; shift 2 ;;
    -h|--help) sed -n '2,16p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "soak.sh: unknown argument '$1' (--help)" >&2; exit 2 ;;
  esac
done
[[ "$LAPS" =~ ^[1-9][0-9]*$ ]] || { echo "soak.sh: --laps expects a whole number >= 1" >&2; exit 2; }
[[ "$WALKERS" =~ ^[0-9]+$ ]] && [ "$((10#$WALKERS))" -le 100 ] ||
  { echo "soak.sh: --walkers expects a whole number from 0 to 100" >&2; exit 2; }
WALKERS=$((10#$WALKERS))
for b in supervisor omni-sim omni-eval odom_mapper rbpf_mapper pose_graph_mapper octomap_builder map_fusion; do
  [ -x "$BUILD/bin/$b" ] || { echo "soak.sh: $BUILD/bin/$b missing: build first (./omni setup)" >&2; exit 1; }
done
# Only a folder this script wrote (its supervisor.yaml says so) or an empty or new one is
# cleared: --out must never take a folder of other work with it.
if [ -d "$OUT" ] && [ -n "$(ls -A "$OUT")" ] &&
   ! grep -qs '^# written by scripts/soak.sh' "$OUT/supervisor.yaml"; then
  echo "soak.sh: $OUT exists and is not a soak run's folder; name a new or empty one" >&2
  exit 2
fi
rm -rf "$OUT"
mkdir -p "$OUT"
OUT="$(cd "$OUT" && pwd)"

child() {
  local name="$1" out="$2"
  echo "  $name:"
  echo "    command: [\"$BUILD/bin/$name\", --config, \"$ROOT/config/$name.yaml\", --out, \"$out\"]"
  echo "    heartbeat: $name"
  case "$name" in
    rbpf_mapper|pose_graph_mapper|octomap_builder)
      echo "    heartbeat_timeout_s: 30"
      echo "    stop_grace_s: 120" ;;
    map_fusion) echo "    stop_grace_s: 60" ;;
  esac
}
{
  echo "# written by scripts/soak.sh"
  echo "children:"
  child map_fusion "$OUT/fusion"
  child odom_mapper "$OUT"
  child rbpf_mapper "$OUT/rbpf"
  child pose_graph_mapper "$OUT/posegraph"
  child octomap_builder "$OUT/octomap"
} > "$OUT/supervisor.yaml"

run='
ip link set lo up && ip route add 224.0.0.0/4 dev lo || exit 98
B="$0"; D="$1"; LAPS="$2"; SPEED="$3"; WALKERS="$4"
export LCM_DEFAULT_URL="udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304"
"$B/bin/supervisor" --config "$D/supervisor.yaml" > "$D/supervisor.log" 2>&1 & s=$!
sleep 2
( while kill -0 $s 2>/dev/null; do
    t=$(date +%s)
    for p in $(pgrep -P $s); do
      n=$(cat /proc/$p/comm 2>/dev/null) || continue
      r=$(awk "/^VmRSS/{print \$2}" /proc/$p/status 2>/dev/null) || continue
      c=$(awk "{print \$14 + \$15}" /proc/$p/stat 2>/dev/null) || continue
      echo "$t $n $r $c"
    done >> "$D/rss.txt"
    sleep 20 & wait $!
  done ) & sampler=$!
rc=0
"$B/bin/omni-sim" --out "$D/sim" --laps "$LAPS" --live "" --speed "$SPEED" --walkers "$WALKERS" > "$D/sim.log" 2>&1 || rc=$?
sleep 5
kill -TERM $s
wait $s || rc=$((rc ? rc : 10))
kill $sampler 2>/dev/null
exit $rc'
rc=0
if [ "$(id -u)" -eq 0 ] && unshare -n true 2>/dev/null; then
  unshare -n bash -c "$run" "$BUILD" "$OUT" "$LAPS" "$SPEED" "$WALKERS" || rc=$?
elif unshare -rn true 2>/dev/null; then
  unshare -rn bash -c "$run" "$BUILD" "$OUT" "$LAPS" "$SPEED" "$WALKERS" || rc=$?
else
  echo "soak.sh: needs a private network namespace (root or user namespaces)" >&2
  exit 1
fi
[ "$rc" = 0 ] || echo "soak.sh: the run did not end cleanly (exit $rc; see $OUT/sim.log, $OUT/supervisor.log)" >&2

[ -s "$OUT/rss.txt" ] || { echo "soak.sh: no process was sampled (see $OUT/supervisor.log)" >&2; exit 1; }
hz=$(getconf CLK_TCK)
echo "memory (RSS) and CPU per process over $LAPS laps at ${SPEED}x, $WALKERS walkers (sampled every 20 s):"
awk -v hz="$hz" -v laps="$LAPS" '
  NR == 1 { t0 = $1 }
  { if (!($2 in first)) { first[$2] = $3; tfirst[$2] = $1 }
    last[$2] = $3; tlast[$2] = $1; cpu[$2] = $4; if ($3 > peak[$2]) peak[$2] = $3
    rows[NR] = $0 }
  END {
    span = 0; for (n in tlast) if (tlast[n] - t0 > span) span = tlast[n] - t0
    lap = span / laps
    for (i = 1; i <= NR; ++i) { split(rows[i], f, " ")
      if (f[1] - t0 <= lap) at1[f[2]] = f[3] }
    printf "  %-18s %12s %12s %12s %14s %10s\n", "process", "after lap 1", "at the end", "peak", "growth/lap", "CPU"
    for (n in last) {
      g = laps > 1 ? (last[n] - at1[n]) / (laps - 1) : 0
      printf "  %-18s %9.1f MB %9.1f MB %9.1f MB %+11.2f MB %8.1f s\n", n, at1[n] / 1024, last[n] / 1024, peak[n] / 1024, g / 1024, cpu[n] / hz
    }
  }' "$OUT/rss.txt"
grep '^omni-sim:' "$OUT/sim.log" 2>/dev/null | sed 's/^/  /' || true
echo "trajectory errors against the simulator's truth:"
for t in odom_trajectory.txt rbpf/trajectory.txt posegraph/trajectory.txt; do
  [ -f "$OUT/$t" ] || { echo "  $t: missing"; continue; }
  printf '  %-26s ' "$t"
  "$BUILD/bin/omni-eval" ate "$OUT/sim/truth.txt" "$OUT/$t" | grep -m1 RMSE || true
done
echo "map errors against the simulator's truth map:"
for m in odom_map.yaml rbpf/map.yaml posegraph/map.yaml octomap/grid.yaml fusion/fused_map.yaml; do
  [ -f "$OUT/$m" ] || { echo "  $m: missing"; continue; }
  printf '  %-26s ' "$m"
  "$BUILD/bin/omni-eval" map "$OUT/sim/truth_map.yaml" "$OUT/$m" | tail -1 || true
done
exit "$rc"
