#!/usr/bin/env bash
# Every benchmark of BENCHMARKS.md, in one go: peers' system packages and the `bench` extra,
# then the suites (results in benchmarks/results/, gitignored). Usage: bash benchmarks/run.sh
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${PYTHON:-.venv/bin/python}"
bash benchmarks/setup.sh "$PY"
lscpu | grep -E "Model name|^CPU\(s\)"
"$PY" -c "import sys, numpy, numba; print('python', sys.version.split()[0], 'numpy', numpy.__version__, 'numba', numba.__version__)"
"$PY" benchmarks/compile_cost.py --cold
"$PY" -m xray_viz.bench bench --out benchmarks/results/full "$@"
"$PY" benchmarks/interactive.py
