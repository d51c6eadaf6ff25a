#!/usr/bin/env bash
# Install what the benchmark peers need: the Debian libraries Open3D and gVXR load, then the
# `bench` extra (open3d, embreex, gvxr). apt-get runs only for missing packages and only as root;
# otherwise the exact command to run is printed. Usage: bash benchmarks/setup.sh [PYTHON]
set -euo pipefail
PY="${1:-python3}"
need=()
# open3d: libusb-1.0-0; gvxr (headless EGL): the xcb helpers below.
for pkg in libusb-1.0-0 libxcb-res0 libxcb-ewmh2 libxcb-composite0 libxcb-xinerama0 \
           libxcb-keysyms1 libxcb-icccm4 libegl1 libgl1; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "installing system packages: ${need[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
  else
    echo "benchmark peers need these Debian packages: ${need[*]}" >&2
    echo "install them with: sudo apt-get install ${need[*]}" >&2
  fi
fi
log="$(mktemp)"
if "$PY" -m pip install --quiet -e '.[bench]' >"$log" 2>&1; then
  echo "bench extra installed (open3d, embreex, gvxr)"
else
  cat "$log" >&2
  echo "pip install -e '.[bench]' failed (output above)" >&2
  rm -f "$log"
  exit 1
fi
rm -f "$log"
