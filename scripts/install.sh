#!/usr/bin/env bash
# Install zcut into ./.venv on a fresh Debian machine (system libraries included), then compile its
# numba kernels once (a first run would otherwise wait in silence: the whole set takes 1.5-9 minutes,
# measured; 17.6 min of wall time on two cores shared by five other jobs). It prints a line per kernel
# group as it goes.
#   bash scripts/install.sh          # runtime only
#   bash scripts/install.sh --test   # plus test tools, Ray (the batch tests start a real cluster) and chromium
set -euo pipefail
cd "$(dirname "$0")/.."
want_test=0
[ "${1:-}" = "--test" ] && want_test=1

# System packages: open3d 0.20 needs libusb-1.0 and libgomp; the browser tests need chromium; the Ray
# test runs its cluster in a network namespace of its own (unshare, ip: util-linux, iproute2).
pkgs=(libusb-1.0-0 libgomp1)
[ $want_test = 1 ] && pkgs+=(chromium iproute2 util-linux)
missing=()
for p in "${pkgs[@]}"; do dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p"); done
if [ ${#missing[@]} -gt 0 ]; then
  SUDO=""; [ "$(id -u)" != 0 ] && SUDO="sudo"
  echo "installing Debian packages: ${missing[*]}"
  # wait for another apt (e.g. unattended upgrades) instead of failing on its lock
  APT=(-o DPkg::Lock::Timeout=600)
  $SUDO apt-get "${APT[@]}" update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get "${APT[@]}" install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

PY=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
if [ $want_test = 1 ]; then
  .venv/bin/python -m pip install -q -e '.[test,ray]'
else
  .venv/bin/python -m pip install -q -e .
fi
.venv/bin/python -m replay.warmup
