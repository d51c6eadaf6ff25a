"""SHA-256 of the path lengths of every bundled phantom, both engines, a few sizes (issue 18).

Usage::

    python benchmarks/image_hashes.py [--out FILE] [--compare FILE] [--engine fast]

Renders (traces) every scene of :func:`xray_viz.phantoms.names` with the fast and the NumPy
engine at a few detector sizes and supersamplings, and prints one line per case with the
SHA-256 of the path-length array (float64 bytes). ``--compare`` reads an earlier output and
reports every case whose hash changed: a before/after check that a speed change leaves every
image bit for bit as it was.
"""

from __future__ import annotations

import argparse
import hashlib
import sys

import numpy as np

import xray_viz
from xray_viz import phantoms
from xray_viz.tracing.engines import ENGINES

CASES = [((64, 48), 1), ((128, 128), 2), ((301, 257), 1), ((512, 512), 1)]


def _scene(name, shape):
    import dataclasses

    scene = xray_viz.load_scene(name)
    det = scene.acquisition.detector
    W, H = det.shape
    pitch = (det.pitch[0] * W / shape[0], det.pitch[1] * H / shape[1])
    new_det = dataclasses.replace(det, shape=shape, pitch=pitch)
    return scene.replace(acquisition=scene.acquisition.replace(detector=new_det))


def _trace(engine, scene, n):
    """``fast-banded``: the fast engine with one-body scenes traced by bands too (the path
    of detectors too large for one accumulator per thread)."""
    if engine != "fast-banded":
        return ENGINES[engine].path_lengths(scene.bodies, scene.acquisition, supersample=n)
    from xray_viz.tracing import fast

    old = fast._DIRECT_MAX_SAMPLES
    fast._DIRECT_MAX_SAMPLES = 0
    try:
        return fast.trace_once(scene, supersample=n)
    finally:
        fast._DIRECT_MAX_SAMPLES = old


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out")
    ap.add_argument("--compare")
    ap.add_argument("--engine", action="append", help="fast, numpy, fast-banded (default: all)")
    args = ap.parse_args(argv)
    lines = []
    for name in phantoms.names():
        for shape, n in CASES:
            scene = _scene(name, shape)
            for engine in args.engine or ["fast", "fast-banded", "numpy"]:
                if engine == "numpy" and shape[0] * shape[1] * n * n > 128 * 128 * 4:
                    continue
                L = _trace(engine, scene, n)
                h = hashlib.sha256(np.ascontiguousarray(L, np.float64).tobytes()).hexdigest()
                line = f"{name} {shape[0]}x{shape[1]} n={n} {engine} {h}"
                print(line, flush=True)
                lines.append(line)
    if args.out:
        with open(args.out, "w") as f:
            f.write("\n".join(lines) + "\n")
    if args.compare:
        old = {" ".join(l.split()[:4]): l.split()[4] for l in open(args.compare) if l.strip()}
        bad = [l for l in lines if old.get(" ".join(l.split()[:4])) not in (None, l.split()[4])]
        missing = [k for k in old if k not in {" ".join(l.split()[:4]) for l in lines}]
        print(f"{len(lines)} cases, {len(bad)} changed, {len(missing)} not run")
        for l in bad:
            print("CHANGED", l)
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
