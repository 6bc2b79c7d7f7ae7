#!/usr/bin/env bash
# Installs rsfm's build and run dependencies from Debian 12's packages.
# Idempotent and non-interactive: does nothing when everything is present.
# Run as root (or with sudo available). Used by `make demo`, `make test` and .ci/run.
set -euo pipefail
PKGS=(build-essential cmake pkg-config
      libeigen3-dev libopencv-dev libceres-dev libcli11-dev nlohmann-json3-dev
      libfmt-dev libgtest-dev libbenchmark-dev libboost-dev
      python3-numpy python3-matplotlib python3-dev pybind11-dev python3-pytest ffmpeg
      opencv-doc visp-images-data)
missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PKGS[@]} packages present" >&2
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then
  command -v sudo >/dev/null || { echo "install-deps: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  SUDO="sudo"
fi
echo "install-deps: installing ${missing[*]}" >&2
export DEBIAN_FRONTEND=noninteractive
APT_OPTS=(-y -q -o DPkg::Lock::Timeout=600 -o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold)
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get -q -o DPkg::Lock::Timeout=600 update >/dev/null
$SUDO env DEBIAN_FRONTEND=noninteractive apt-get install --no-install-recommends "${APT_OPTS[@]}" "${missing[@]}" >/dev/null
echo "install-deps: done" >&2
