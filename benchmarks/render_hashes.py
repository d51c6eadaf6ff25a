"""SHA-256 of the rendered images (intensity, line integral, total path length) of every
bundled phantom with the detector model's options on and off, both engines, and of a scan.

Usage::

    python benchmarks/render_hashes.py [--out FILE] [--compare FILE] [--quick]

:mod:`benchmarks.image_hashes` checks the engines' path lengths; this checks what the physics
makes of them (spectra, heel effect, scintillator, focal spot, MTF, fall-off, noise with a
seed, gain), and a scan of 8 projections with noise: a before/after check that a change of
the pipeline's structure leaves every image bit for bit as it was.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import sys

import numpy as np

import xray_viz
from xray_viz import phantoms

SPECTRUM = {"kvp": 80.0, "filters": {"Al": 2.0}}

VARIANTS = {
    "plain": ({}, {}, 1),
    "ss2": ({}, {}, 2),
    "moved": ({"position": "moved"}, {}, 1),
    "offset": ({}, {"offset": (3.0, -2.0)}, 1),
    "full": ({"spectrum": SPECTRUM, "heel": True},
             {"noise": True, "seed": 3, "falloff": True, "focal_spot": 0.4, "i0": 1000.0,
              "scintillator": {"material": "CsI", "thickness": 0.5}, "mtf": {"sigma": 0.4},
              "electronic_noise": 2.0, "gain": 2.0}, 1),
    "counting": ({"spectrum": SPECTRUM}, {"response": "counting", "noise": True, "seed": 5,
                                          "i0": 500.0, "falloff": True}, 2),
    "kerma": ({"spectrum": SPECTRUM}, {"response": "kerma", "focal_spot": 0.3}, 1),
    "energy-noise": ({"spectrum": SPECTRUM}, {"noise": True, "seed": 9, "i0": 2000.0}, 1),
}


def _h(a) -> str:
    return hashlib.sha256(np.ascontiguousarray(a, np.float64).tobytes()).hexdigest()[:24]


def small(scene, shape=(96, 80)):
    det = scene.detector
    W, H = det.shape
    pitch = (det.pitch[0] * W / shape[0], det.pitch[1] * H / shape[1])
    return scene.replace(detector=dataclasses.replace(det, shape=shape, pitch=pitch))


def variant(scene, src_changes, det_changes):
    src = {**src_changes}
    if src.get("position") == "moved":
        src["position"] = np.asarray(scene.source.position) + [30.0, -20.0, 50.0]
    det = {**det_changes}
    if "scintillator" in det:
        from xray_viz.physics.detector import scintillator_from_dict

        det["scintillator"] = scintillator_from_dict(det["scintillator"])
    if "mtf" in det:
        from xray_viz.physics.detector import mtf_from_dict

        det["mtf"] = mtf_from_dict(det["mtf"])
    return scene.replace(source=dataclasses.replace(scene.source, **src) if src else scene.source,
                         detector=dataclasses.replace(scene.detector, **det) if det
                         else scene.detector)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out")
    ap.add_argument("--compare")
    args = ap.parse_args(argv)
    lines = []

    def add(key, value):
        print(key, value, flush=True)
        lines.append(f"{key} {value}")

    for name in phantoms.names():
        base = small(xray_viz.load_scene(name))
        for vname, (s, d, n) in VARIANTS.items():
            scene = variant(base, s, d)
            for engine in ("fast", "numpy"):
                if engine == "numpy" and vname not in ("plain", "full", "counting"):
                    continue
                r = xray_viz.render(scene, engine=engine, supersample=n)
                add(f"{name} {vname} {engine}",
                    f"{_h(r.intensity)} {_h(r.line_integral)} {_h(r.total_path_length)}")
    from xray_viz.orbit import Orbit

    frog = small(xray_viz.load_scene("frog"), (64, 48))
    for vname in ("plain", "full", "counting"):
        scene = variant(frog, *VARIANTS[vname][:2])
        orbit = Orbit(projections=8, axis=[0, 1, 0])
        for quantity in ("line-integral", "intensity"):
            s = xray_viz.scan(scene, orbit, quantity=quantity)
            add(f"scan-frog {vname} {quantity}", _h(np.asarray(s.projections[:])))
    if args.out:
        with open(args.out, "w") as f:
            f.write("\n".join(lines) + "\n")
    if args.compare:
        now = {" ".join(l.split(" ", 3)[:3]): l.split(" ", 3)[3] for l in lines}
        old = {" ".join(l.split(" ", 3)[:3]): l.rstrip("\n").split(" ", 3)[3]
               for l in open(args.compare) if l.strip()}
        bad = [k for k in now if old.get(k) not in (None, now[k])]
        print(f"{len(now)} cases, {len(bad)} changed, {len(set(old) - set(now))} not run")
        for k in bad:
            print("CHANGED", k)
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
