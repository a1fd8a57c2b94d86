#!/usr/bin/env bash
# Installs the Debian packages Tactus needs, only those missing (idempotent; instant when all present).
# Uses sudo when not root. Set TACTUS_SKIP_DEPS=1 to skip entirely. Arguments name extra packages
# to install the same way (e.g. scripts/bench-solver: libsiconos-numerics-dev).
set -euo pipefail
[[ "${TACTUS_SKIP_DEPS:-0}" == "1" ]] && exit 0
packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libboost-dev libspdlog-dev libsuitesparse-dev libyaml-cpp-dev
  libcli11-dev libgtest-dev libgmock-dev libbenchmark-dev zlib1g-dev
  python3 python3-matplotlib python3-dev python3-numpy python3-pytest pybind11-dev
  libhdf5-dev
  libopenblas0-serial
  chromium
)
packages+=("$@")
# node and npm build the live view's page (three.js); from Debian only when no node is installed
command -v node >/dev/null 2>&1 || packages+=(nodejs npm)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[[ ${#missing[@]} -eq 0 ]] && exit 0
echo "tactus: installing missing Debian packages: ${missing[*]}"
sudo=""
if [[ $(id -u) -ne 0 ]]; then
  command -v sudo >/dev/null || { echo "tactus: need root or sudo to install: ${missing[*]}" >&2; exit 1; }
  sudo="sudo"
fi
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq >/dev/null
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
