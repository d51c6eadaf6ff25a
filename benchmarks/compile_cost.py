"""First-call (compile) and cached (new process) cost of the fast engine.

Usage: python benchmarks/compile_cost.py [--cold]   (--cold deletes numba's cache first)

Each process imports xray_viz, traces the one-body sphere twice, then a several-bodies scene
(nested_spheres), whose kernels compile (or load from the cache) on their first use.
"""
import subprocess
import sys
import time
from pathlib import Path

CHILD = r"""
import time
t0 = time.perf_counter()
import xray_viz
from xray_viz.tracing.fast import trace_once
t1 = time.perf_counter()
scene = xray_viz.load_scene("sphere")
t2 = time.perf_counter()
trace_once(scene)
t3 = time.perf_counter()
trace_once(scene)
t4 = time.perf_counter()
multi = xray_viz.load_scene("nested_spheres")        # several bodies: other kernels
t5 = time.perf_counter()
trace_once(multi)
t6 = time.perf_counter()
print(f"import {t1 - t0:.2f} s, first trace (compile or cache load) {t3 - t2:.2f} s, "
      f"second trace {1e3 * (t4 - t3):.1f} ms; first several-bodies trace {t6 - t5:.2f} s")
"""

if __name__ == "__main__":
    if "--cold" in sys.argv:
        import xray_viz.tracing as tr
        cache = Path(tr.__file__).parent / "__pycache__"
        # every numba kernel of the tracing package (cache=True writes one .nbi/.nbc pair each)
        for f in list(cache.glob("*.nbi")) + list(cache.glob("*.nbc")):
            f.unlink()
        print("numba cache cleared")
    from xray_viz import progress

    progress.configure(enabled=sys.stderr.isatty())
    for label in progress.iterate(("process 1", "process 2 (cached)"), "compile cost",
                                  unit="processes"):
        t = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True)
        progress.echo(f"{label}: {out.stdout.strip()} {out.stderr.strip()[-300:]}")
