"""Compile CPU time of each fast-engine kernel in a fresh process with an empty numba cache.

Usage::

    python benchmarks/compile_profile.py [KERNEL ...] [--opt N]

One process per kernel (so each figure includes the helpers it inlines and the NumPy
allocation implementations it is the first to need), ``NUMBA_CACHE_DIR`` a new temporary
directory. Prints CPU seconds of the import of the engine and of the compile itself, and the
same from numba's compile events (inclusive time of the kernel's own compile).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile

CHILD = r"""
import json, sys, time
t0 = time.process_time()
from xray_viz.tracing import _raster as R
t1 = time.process_time()
for name in sys.argv[1:]:
    R.KERNELS.kernel(name)
t2 = time.process_time()
print(json.dumps({"import": t1 - t0, "compile": t2 - t1}))
"""


def main(argv=None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    env = dict(os.environ)
    if "--opt" in args:
        i = args.index("--opt")
        env["NUMBA_OPT"] = args[i + 1]
        del args[i:i + 2]
    from xray_viz.tracing import _raster as R

    names = args or list(R.SIGNATURES)
    total = 0.0
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            env["NUMBA_CACHE_DIR"] = tmp
            out = subprocess.run([sys.executable, "-c", CHILD, *name.split("+")], env=env,
                                 capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.splitlines()[-1])
        total += r["compile"]
        print(f"{name:40s} import {r['import']:5.2f} s  compile {r['compile']:5.2f} s CPU",
              flush=True)
    print(f"{'sum':40s} {'':14s}  compile {total:5.2f} s CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())
