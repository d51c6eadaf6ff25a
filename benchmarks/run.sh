#!/usr/bin/env bash
# Every benchmark of BENCHMARKS.md, in one go: peers' system packages and the `bench` extra,
# then the suites (results in benchmarks/results/, gitignored). Usage: bash benchmarks/run.sh
# [extra arguments for `xray-viz bench`, e.g. --quick or --repeat 9]
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-.venv/bin/python}"
bash benchmarks/setup.sh "$PY"
echo "== machine"
lscpu | grep -E "Model name|^CPU\(s\)|Hypervisor"
echo "nproc $(nproc); $(free -g | awk '/Mem:/ {print $2 " GiB RAM"}'); load: $(cut -d' ' -f1-3 /proc/loadavg)"
echo "== packages"
"$PY" - <<'PY'
import sys
from importlib.metadata import PackageNotFoundError, version
names = ["numpy", "numba", "trimesh", "pyvista", "pymeshlab", "open3d", "embreex", "gvxr",
         "matplotlib"]
def v(n):
    try:
        return version(n)
    except PackageNotFoundError:
        return "missing"
print("python", sys.version.split()[0], ", ".join(f"{n} {v(n)}" for n in names))
PY
if command -v git >/dev/null && git rev-parse --git-dir >/dev/null 2>&1; then
  echo "== code: $(git rev-parse --short HEAD); uncommitted changes in the engine:"
  git diff --stat -- xray_viz/tracing || true
fi
echo "== numba compile cost"
"$PY" benchmarks/compile_cost.py --cold
echo "== suites"
"$PY" benchmarks/suites.py --out benchmarks/results/full "$@"
echo "== interactive preview"
"$PY" benchmarks/interactive.py
