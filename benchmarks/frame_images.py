"""Rendered images of every bundled phantom in 13 physics variants: save, or compare (issue 18).

Usage::

    python benchmarks/frame_images.py save before.npz      # in the before-tree
    python benchmarks/frame_images.py compare before.npz   # in this tree

``benchmarks/image_hashes.py`` checks the path lengths bit for bit; this checks what the image
step makes of them: ``intensity``, ``line_integral`` and ``total_path_length`` of
``xray_viz.render`` for each phantom as bundled, and (at half its detector size) with
supersample 2, fall-off with a gain, an 80 kV tube, the tube supersampled, a counting
detector, the heel effect, heel + fall-off + supersample 2, a CsI scintillator, a focal spot,
an MTF, polychromatic noise with electronic noise and monochromatic noise (fixed seeds).
``compare`` prints every image whose largest difference exceeds 1e-12 of its largest value,
and how many are bit for bit the same.
"""

from __future__ import annotations

import dataclasses
import sys
import warnings

import numpy as np

import xray_viz
from xray_viz import phantoms

TUBE = {"kvp": 80.0, "filters": {"Al": 2.5}, "bin": 2.0}


def _shrink(scene, f=2):
    det = scene.detector
    W, H = det.shape
    shape = (max(8, W // f), max(8, H // f))
    pitch = (det.pitch[0] * W / shape[0], det.pitch[1] * H / shape[1])
    return scene.replace(detector=dataclasses.replace(det, shape=shape, pitch=pitch))


def _det(scene, **changes):
    return scene.replace(detector=dataclasses.replace(scene.detector, **changes))


def variants(name):
    """``(tag, scene, render keywords)`` of one phantom."""
    s = xray_viz.load_scene(name)
    yield "plain", s, {}
    s2 = _shrink(s)
    yield "ss2", s2, {"supersample": 2}
    yield "falloff", _det(s2, falloff=True, i0=1e4, gain=2.5), {}
    tube = s2.replace(source=dataclasses.replace(s2.source, spectrum=TUBE))
    yield "tube", tube, {}
    yield "tube-ss2", tube, {"supersample": 2}
    yield "tube-counting", _det(tube, response="counting"), {}
    if s.source.kind == "point":
        heel = tube.replace(source=dataclasses.replace(tube.source, heel=True))
        yield "heel", heel, {}
        yield "heel-falloff-ss2", _det(heel, falloff=True), {"supersample": 2}
    yield "scint", _det(tube, scintillator={"material": "CsI", "thickness": 0.5}), {}
    yield "focal", _det(s2, focal_spot=1.0, falloff=True), {}
    yield "mtf", _det(s2, mtf={"sigma": 0.3}), {}
    yield "noise", _det(tube, noise=True, seed=3, i0=1e4, electronic_noise=2.0,
                        falloff=True), {}
    yield "noise-mono", _det(s2, noise=True, seed=4, i0=1e3), {}


def images() -> dict:
    out = {}
    for name in phantoms.names():
        for tag, scene, kw in variants(name):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                image = xray_viz.render(scene, **kw)
            for q in ("intensity", "line_integral", "total_path_length"):
                out[f"{name}/{tag}/{q}"] = np.array(getattr(image, q))
    return out


def compare(ref, imgs) -> int:
    worst, bad, same = 0.0, 0, 0
    if set(ref.files) != set(imgs):
        print("different cases:", sorted(set(ref.files) ^ set(imgs)))
        return 1
    for k in ref.files:
        a, b = ref[k], imgs[k]
        scale = max(float(np.abs(a[np.isfinite(a)]).max(initial=0.0)), 1e-300)
        d = float(np.where(a == b, 0.0, np.abs(a - b)).max(initial=0.0)) / scale
        same += bool(np.array_equal(a, b))
        worst = max(worst, d)
        if not d <= 1e-12:
            bad += 1
            print("DIFF", k, d)
    print(f"{len(imgs)} images: {same} bit for bit the same, worst relative difference "
          f"{worst:.3g}, {bad} over 1e-12")
    return 1 if bad else 0


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[0] not in ("save", "compare"):
        print(__doc__)
        return 2
    imgs = images()
    if argv[0] == "save":
        np.savez(argv[1], **imgs)
        print(f"{len(imgs)} images saved to {argv[1]}")
        return 0
    return compare(np.load(argv[1]), imgs)


if __name__ == "__main__":
    sys.exit(main())
