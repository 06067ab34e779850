#!/bin/bash
# Installs the stack as a systemd service on the robot PC: the supervisor (and through it every
# process in its config) starts at boot, restarts if it fails, and on `systemctl stop` gets
# SIGTERM alone, so it stops its children one at a time and the mappers write their maps.
#
# usage: scripts/install-service.sh [--print] [--name NAME] [--user USER]
#                                   [--config FILE] [--url LCM_URL] [--can IF [--bitrate BPS]]
#                                   [--build DIR]
#   --print        write the unit to stdout instead of installing it (review, or tests)
#   --name NAME    unit name (default omni: /etc/systemd/system/omni.service)
#   --user USER    run as this user (default: the owner of the repository); it needs the
#                  devices (dialout group for the serial ports) and write access to the maps
#   --config FILE  supervisor config (default config/supervisor.yaml), relative to the repo
#   --url URL      LCM_DEFAULT_URL for every process
#                  (default udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304)
#   --can IF       bring the SocketCAN interface up before the stack starts (as root) ...
#   --bitrate BPS  ... at this bit rate (default 1000000, the firmware's)
#   --build DIR    the build tree whose bin/supervisor runs (default build/)
# Needs a built tree (build/bin/supervisor). Installing needs root; then:
#   systemctl enable --now omni      # start now and at every boot
#   journalctl -u omni -f            # the supervisor's and the processes' logs
set -euo pipefail

ROOT="$(cd "$(dirname "$(readlink -f "${BASH_SOURCE[0]}")")/.." && pwd)"
PRINT=0
NAME=omni
RUN_USER="$(stat -c %U "$ROOT")"
CONFIG=config/supervisor.yaml
URL="udpm://239.255.76.67:7667?ttl=0&recv_buf_size=4194304"
CAN_IF=""
BITRATE=1000000
BUILD="$ROOT/build"

die() {
  echo "install-service: $*" >&2
  exit 2
}

while [ $# -gt 0 ]; do
  case "$1" in
    --print) PRINT=1 ;;
    --name) NAME="${2:?--name needs a value}"; shift ;;
    --user) RUN_USER="${2:?--user needs a value}"; shift ;;
    --config) CONFIG="${2:?--config needs a value}"; shift ;;
    --url) URL="${2:?--url needs a value}"; shift ;;
    --can) CAN_IF="${2:?--can needs a value}"; shift ;;
    --bitrate) BITRATE="${2:?--bitrate needs a value}"; shift ;;
    --build) BUILD="$(cd "${2:?--build needs a value}" && pwd)"; shift ;;
    -h | --help) awk 'NR > 1 && !/^#/ {exit} NR > 1 {sub(/^# ?/, ""); print}' "$0"; exit 0 ;;
    *) die "unknown option '$1' (see --help)" ;;
  esac
  shift
done

[[ "$NAME" =~ ^[A-Za-z0-9_.@-]+$ ]] || die "--name '$NAME': letters, digits, '_', '.', '-' only"
[[ "$BITRATE" =~ ^[0-9]+$ ]] || die "--bitrate '$BITRATE' is not a number"
id "$RUN_USER" >/dev/null 2>&1 || die "--user '$RUN_USER': no such user"
[ -x "$BUILD/bin/supervisor" ] || die "$BUILD/bin/supervisor not built (./omni setup)"
case "$CONFIG" in /*) CONFIG_PATH="$CONFIG" ;; *) CONFIG_PATH="$ROOT/$CONFIG" ;; esac
[ -f "$CONFIG_PATH" ] || die "config '$CONFIG_PATH' not found"
# The unit only brings the interface up and starts the supervisor: what the children run is in
# the config. Say so when the options and the config disagree, rather than install a mismatch.
[ -z "$CAN_IF" ] || [[ "$CAN_IF" =~ ^[A-Za-z0-9_-]+$ ]] || die "--can '$CAN_IF' is not an interface name"
# (Comments left out; quotes and spacing as YAML allows; the interface as a whole word.)
config_lines="$(grep -v '^[[:space:]]*#' "$CONFIG_PATH" || true)"
if [ -n "$CAN_IF" ] && grep -q -- "--can" <<<"$config_lines" &&
  ! grep -Eq -- "(^|[^A-Za-z0-9_-])(socketcan:)?$CAN_IF([^A-Za-z0-9_-]|\$)" <<<"$config_lines"; then
  echo "install-service: warning: $CONFIG_PATH does not run the base bridge on $CAN_IF" \
    "(--can only brings the interface up; set the bridge's --can in the config)" >&2
fi
if [ "$BUILD" != "$ROOT/build" ] && grep -q "build/bin/" <<<"$config_lines"; then
  echo "install-service: warning: the children in $CONFIG_PATH run build/bin/... from $ROOT," \
    "not from $BUILD (--build chooses only the supervisor's binary)" >&2
fi

# The supervisor's worst-case orderly stop is the sum of its children's stop_grace_s (default
# 5 s each); systemd must wait longer than that before it kills what is left. The children are
# the keys at the indentation of the first line under `children:`, whatever it is (two spaces
# were assumed: a config indented by four counted no child) and whatever their names hold
# (`can-up` was missed); a grace is read where it stands on its line (also in `{...}` form).
GRACE=$(awk '
  /^[[:space:]]*(#|$)/ { next }
  /^children:/ { c = 1; next }
  c && /^[^[:space:]]/ { c = 0 }
  c && ind == 0 { match($0, /^[[:space:]]*/); ind = RLENGTH }
  c { match($0, /^[[:space:]]*/)
      if (RLENGTH == ind && $0 ~ /^[[:space:]]*[^[:space:]#-][^:]*:/) n++ }
  c && match($0, /stop_grace_s:[[:space:]]*[0-9.]+/) {
    v = substr($0, RSTART, RLENGTH); sub(/stop_grace_s:[[:space:]]*/, "", v); s += v; g++ }
  END { print s + 5 * (n - g) }' "$CONFIG_PATH")
STOP_TIMEOUT=$((GRACE + 30))

unit() {
  cat <<EOF
# Generated by scripts/install-service.sh from $ROOT
[Unit]
Description=omni robot stack (supervisor: drivers, base bridge, mappers, map fusion)
Wants=network-online.target
After=network-online.target

[Service]
Type=simple
User=$RUN_USER
WorkingDirectory=$ROOT
Environment="LCM_DEFAULT_URL=$URL"
EOF
  # What the bus needs and a reboot forgets: the receive buffers the processes ask for
  # (recv_buf_size) are capped by rmem_max, and UDP multicast needs a route for 224.0.0.0/4,
  # which a PC off the network at boot has not: then one on the loopback, so the stack runs
  # (ttl=0 keeps the traffic on the machine anyway).
  echo "ExecStartPre=+-/sbin/sysctl -q -w net.core.rmem_max=8388608"
  echo "ExecStartPre=+-/bin/sh -c 'ip route get 224.0.0.1 >/dev/null 2>&1 || ip route add 224.0.0.0/4 dev lo'"
  if [ -n "$CAN_IF" ]; then
    echo "ExecStartPre=+-/sbin/ip link set $CAN_IF down"
    echo "ExecStartPre=+/sbin/ip link set $CAN_IF up type can bitrate $BITRATE restart-ms 100"
  fi
  cat <<EOF
ExecStart="$BUILD/bin/supervisor" --config "$CONFIG_PATH"
# SIGTERM to the supervisor only: it stops its children newest first, each within its
# stop_grace_s (sum $GRACE s here); whatever is left after TimeoutStopSec is killed.
KillSignal=SIGTERM
KillMode=mixed
TimeoutStopSec=$STOP_TIMEOUT
Restart=on-failure
RestartSec=5

[Install]
WantedBy=multi-user.target
EOF
}

if [ "$PRINT" = 1 ]; then
  unit
  exit 0
fi
[ "$(id -u)" = 0 ] || die "installing needs root (or use --print)"
TARGET="/etc/systemd/system/$NAME.service"
unit >"$TARGET"
systemctl daemon-reload 2>/dev/null || echo "install-service: systemd is not running here; the unit is written" >&2
echo "install-service: wrote $TARGET; start it with: systemctl enable --now $NAME"
