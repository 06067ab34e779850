#!/usr/bin/env bash
# Installs every Debian 12 package omni needs. Idempotent; needs root (or sudo).
# Nothing is downloaded from anywhere but the configured Debian archive.
# --fuzz: also clang and its libFuzzer runtime, for ./omni fuzz (not needed to build or test).
# --spy: only a Java runtime with its desktop (AWT) libraries, for ./omni spy (lcm-spy).
set -euo pipefail

PACKAGES=(
  # toolchain
  build-essential cmake ninja-build ccache pkg-config git clang-format
  # core libraries
  libeigen3-dev libyaml-cpp-dev zlib1g-dev libgtest-dev libgmock-dev libbenchmark-dev
  # bus: LCM (C/C++ library, lcm-gen and tools, Java for lcm-spy)
  liblcm-dev liblcm-bin liblcm-java libjchart2d-java libglib2.0-dev default-jdk-headless
  # mapping back ends
  libceres-dev liboctomap-dev libpng-dev libbz2-dev libjpeg-dev
  # peers the benchmarks run beside ours (MRPT graph-slam, rbpf-slam)
  mrpt-apps mrpt-common
  # hardware
  libsocketcan-dev libusb-1.0-0-dev libopenni2-dev
  # firmware cross toolchain (Cortex-M4)
  gcc-arm-none-eabi libnewlib-arm-none-eabi binutils-arm-none-eabi
  # process isolation for multi-process runs (unshare, ip)
  util-linux iproute2 bzip2
  # the service unit's check in the tests (systemd-analyze verify); scripts/analysis/*.py
  systemd python3
)
if [ "${1:-}" = "--fuzz" ]; then
  PACKAGES+=(clang libclang-rt-14-dev)
elif [ "${1:-}" = "--spy" ]; then
  PACKAGES=(default-jre)  # only what lcm-spy needs beyond the build (a display PC may not build)
elif [ $# -gt 0 ]; then
  echo "usage: scripts/install-deps.sh [--fuzz | --spy]" >&2
  exit 2
fi

missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PACKAGES[@]} packages already installed"
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  SUDO=sudo
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -q
$SUDO apt-get install -y -q --no-install-recommends "${missing[@]}"
