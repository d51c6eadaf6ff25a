"""Scatter the simulator leaves out: scatter-to-primary ratios (SPR) by a small Monte Carlo.

xray_viz models primary radiation only. This script estimates what fraction of the detected
signal scatter would add, for water slabs (reference cases) and for each bundled phantom
approximated by a box or ellipsoid of its bounding box, filled with water (tissue phantoms) or
aluminium (the step wedge), at 80 kV (SpekPy, 2.5 mm Al), with the phantom's own air gap to the
detector and a parallel beam covering the object.

Physics (xraylib cross sections, the data the bodies use): photoabsorption (the photon is
absorbed; fluorescence of water and Al is neglected), Compton scattering by the Klein-Nishina
cross section times the incoherent scattering function S(x)/Z (rejection sampling), Rayleigh
scattering by the Thomson cross section times the squared form factor (independent atoms, no
molecular interference), no Doppler broadening. The detector is an ideal energy-integrating
one in the plane behind the object; SPR is scored in a disk on the axis (radius 30 mm, or 30 %
of the object's smaller half-width if less), the primary is the exact Beer-Lambert value
averaged over that disk (checked against the Monte Carlo's own unscattered photons, column
"prim. MC/exact"). The photons run in batches; "+-" is the standard error of the batch mean.

Usage: .venv/bin/python benchmarks/scatter_spr.py [--photons 400000] [--seed 1]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np
import xraylib

HC = 12.398419843320026            # keV * Angstrom


class Medium:
    """Cross sections (1/mm) on a fine energy grid and the angular factors of one material."""

    def __init__(self, material: str, density: float, kvp: float):
        self.e = np.linspace(1.0, kvp + 1.0, 4 * int(kvp) + 5)
        cs = [[f(material, float(e)) for e in self.e] for f in
              (xraylib.CS_Photo_CP, xraylib.CS_Compt_CP, xraylib.CS_Rayl_CP)]
        self.mu = np.array(cs) * density / 10.0                       # (3, n) 1/mm
        try:
            comp = xraylib.GetCompoundDataNISTByName(material)
            zs, ws = comp["Elements"], comp["massFractions"]
        except ValueError:
            comp = xraylib.CompoundParser(material)
            zs, ws = comp["Elements"], comp["massFractions"]
        n = [w / xraylib.AtomicWeight(z) for z, w in zip(zs, ws)]   # atoms per gram (rel.)
        self.q = np.linspace(0.0, kvp / HC * 1.01, 2001)               # momentum transfer
        self.f2 = sum(ni * np.array([xraylib.FF_Rayl(z, q) for q in self.q]) ** 2
                      for ni, z in zip(n, zs))
        self.f2 /= self.f2[0]                                        # F^2(x) / F^2(0)
        s = sum(ni * np.array([xraylib.SF_Compt(z, q) if q > 0 else 0.0 for q in self.q])
                for ni, z in zip(n, zs))
        self.s = s / sum(ni * z for ni, z in zip(n, zs))             # S(x) / Z

    def coefficients(self, e):
        return np.array([np.interp(e, self.e, m) for m in self.mu])    # (3, n)


def _box_exit(pos, d, half):
    """Distance along d from pos (inside) to the surface of the box |x_i| <= half_i."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (half - pos) / d, np.where(d < 0, (-half - pos) / d, np.inf))
    return t.min(axis=1)


def _ellipsoid_exit(pos, d, half):
    """Distance along d from pos (inside) to the ellipsoid sum (x_i / half_i)^2 = 1."""
    p, v = pos / half, d / half
    a, b, c = (v * v).sum(1), 2 * (p * v).sum(1), (p * p).sum(1) - 1.0
    return (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a)


def _rotate(d, cos_t, rng):
    """Turn unit directions d by polar angle acos(cos_t), uniform azimuth."""
    phi = rng.uniform(0, 2 * math.pi, len(d))
    sin_t = np.sqrt(np.maximum(1 - cos_t ** 2, 0.0))
    # an orthonormal frame around d
    a = np.where(np.abs(d[:, [2]]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, a)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(d, u)
    out = (d * cos_t[:, None] + u * (sin_t * np.cos(phi))[:, None]
           + w * (sin_t * np.sin(phi))[:, None])
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _sample_compton(e, medium, rng):
    """cos(theta) and scattered energy: Klein-Nishina x S(x)/Z, by rejection."""
    cos_t = np.empty(len(e))
    todo = np.arange(len(e))
    while len(todo):
        c = rng.uniform(-1, 1, len(todo))
        k = e[todo] / 510.99895
        ratio = 1.0 / (1 + k * (1 - c))                                # E'/E
        kn = ratio ** 2 * (ratio + 1 / ratio - (1 - c * c)) / 2.0        # <= 1
        x = e[todo] / HC * np.sqrt((1 - c) / 2)
        accept = rng.uniform(0, 1, len(todo)) < kn * np.interp(x, medium.q, medium.s)
        cos_t[todo[accept]] = c[accept]
        todo = todo[~accept]
    return cos_t, e / (1 + e / 510.99895 * (1 - cos_t))


def _sample_rayleigh(e, medium, rng):
    cos_t = np.empty(len(e))
    todo = np.arange(len(e))
    while len(todo):
        c = rng.uniform(-1, 1, len(todo))
        x = e[todo] / HC * np.sqrt((1 - c) / 2)
        p = (1 + c * c) / 2 * np.interp(x, medium.q, medium.f2)
        accept = rng.uniform(0, 1, len(todo)) < p
        cos_t[todo[accept]] = c[accept]
        todo = todo[~accept]
    return cos_t


def simulate(spectrum, medium, *, shape, half, gap, photons, rng):
    """SPR on the axis behind a box or ellipsoid (half-sizes mm) with the beam along -z."""
    exit_fn = _box_exit if shape == "box" else _ellipsoid_exit
    half = np.asarray(half, float)
    r_score = min(30.0, 0.3 * float(min(half[0], half[1])))
    n = photons
    e = rng.choice(spectrum.energies, size=n, p=spectrum.weights)
    # uniform over the object's cross-section (z = entrance surface)
    if shape == "box":
        xy = rng.uniform(-1, 1, (n, 2)) * half[:2]
        z = np.full(n, half[2])
        area = 4 * half[0] * half[1]
    else:
        r, t = np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * math.pi, n)
        xy = np.c_[r * np.cos(t) * half[0], r * np.sin(t) * half[1]]
        z = half[2] * np.sqrt(np.maximum(1 - (xy ** 2 / half[:2] ** 2).sum(1), 0.0))
        area = math.pi * half[0] * half[1]
    pos = np.c_[xy, z * (1 - 1e-12)]
    d = np.tile([0.0, 0.0, -1.0], (n, 1))
    scattered = np.zeros(n, bool)
    z_det = -half[2] - gap
    tally = {"scatter": 0.0, "primary": 0.0}
    while len(e):
        mu = medium.coefficients(e)
        s = -np.log(rng.uniform(0, 1, len(e))) / mu.sum(0)
        leave = s >= exit_fn(pos, d, half)
        # leaving photons that travel towards the detector: do they hit the scoring disk?
        go = leave & (d[:, 2] < 0)
        t = (z_det - pos[go, 2]) / d[go, 2]
        hit = np.hypot(pos[go, 0] + t * d[go, 0], pos[go, 1] + t * d[go, 1]) < r_score
        energy = e[go][hit]
        tally["scatter"] += energy[scattered[go][hit]].sum()
        tally["primary"] += energy[~scattered[go][hit]].sum()
        stay = ~leave
        pos, d, e, scattered, s, mu = (pos[stay] + d[stay] * s[stay, None], d[stay], e[stay],
                                       scattered[stay], s[stay], mu[:, stay])
        kind = (rng.uniform(0, 1, len(e))[None, :] * mu.sum(0) > np.cumsum(mu, 0)).sum(0)
        keep = kind > 0                                              # 0: photoabsorbed
        pos, d, e, scattered, kind = pos[keep], d[keep], e[keep], scattered[keep], kind[keep]
        comp, rayl = kind == 1, kind == 2
        cos_t = np.empty(len(e))
        cos_t[comp], e[comp] = _sample_compton(e[comp], medium, rng)
        cos_t[rayl] = _sample_rayleigh(e[rayl], medium, rng)
        d = _rotate(d, cos_t, rng)
        scattered[:] = True
        low = e > 1.0
        pos, d, e, scattered = pos[low], d[low], e[low], scattered[low]
    # Beer-Lambert through the object, averaged over the scoring disk (a polar grid)
    rr, aa = np.meshgrid((np.arange(200) + 0.5) / 200, np.arange(64) * 2 * math.pi / 64)
    rr = r_score * np.sqrt(rr.ravel())
    x, y = rr * np.cos(aa.ravel()), rr * np.sin(aa.ravel())
    if shape == "box":
        thickness = np.full(x.shape, 2 * half[2])
    else:
        thickness = 2 * half[2] * np.sqrt(np.maximum(1 - (x / half[0]) ** 2
                                                     - (y / half[1]) ** 2, 0.0))
    mu_total = medium.coefficients(spectrum.energies).sum(0)
    transmitted = np.exp(-np.outer(thickness, mu_total)) @ (spectrum.weights * spectrum.energies)
    exact_primary = (photons / area) * math.pi * r_score ** 2 * float(transmitted.mean())
    return tally["scatter"] / exact_primary, tally["primary"] / exact_primary


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photons", type=int, default=400_000, help="per batch")
    parser.add_argument("--batches", type=int, default=5)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    import xray_viz
    from xray_viz.physics.spectra import tube_spectrum

    spectrum = tube_spectrum(80.0, filters={"Al": 2.5})
    water = Medium("Water, Liquid", 1.0, 80.0)
    aluminium = Medium("Al", 2.699, 80.0)
    rng = np.random.default_rng(args.seed)
    cases = [(f"water slab {t} cm, 30 x 30 cm, no gap", water, "box", (150, 150, 5 * t), 0.0)
             for t in (2, 5, 10, 20)]
    cases.append(("water slab 20 cm, 10 x 10 cm, no gap", water, "box", (50, 50, 100), 0.0))
    cases.append(("water slab 20 cm, 30 x 30 cm, 20 cm gap", water, "box", (150, 150, 100),
                  200.0))
    shapes = {"frog": ("ellipsoid", water), "limb": ("box", water),
              "nested_spheres": ("ellipsoid", water), "shepp_logan": ("ellipsoid", water),
              "sphere": ("ellipsoid", water), "step_wedge": ("box", aluminium)}
    for name, (shape, medium) in shapes.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            scene = xray_viz.load_scene(name)
        tris = scene.triangles.reshape(-1, 3)
        lo, hi = tris.min(0), tris.max(0)
        half = (hi - lo) / 2
        if name == "step_wedge":
            half[2] = half[2] / 2                                    # its mean thickness
        gap = float(lo[2] - scene.detector.center[2])
        label = (f"{name}: {shape} {2 * half[0]:.0f} x {2 * half[1]:.0f} x {2 * half[2]:.0f} mm"
                 f" {'Al' if medium is aluminium else 'water'}, gap {gap:.0f} mm")
        cases.append((label, medium, shape, half, gap))
    print("| case | SPR | scatter fraction S/(S+P) | prim. MC/exact | s |")
    print("|---|---|---|---|---|")
    for label, medium, shape, half, gap in cases:
        t = time.perf_counter()
        runs = np.array([simulate(spectrum, medium, shape=shape, half=half, gap=gap,
                                  photons=args.photons, rng=rng) for _ in range(args.batches)])
        mean, sem = runs.mean(0), runs.std(0, ddof=1) / math.sqrt(len(runs))
        spr = mean[0]
        print(f"| {label} | {spr:.3f} +- {sem[0]:.3f} | {spr / (1 + spr):.3f} | "
              f"{mean[1]:.3f} +- {sem[1]:.3f} | {time.perf_counter() - t:.0f} |", flush=True)


if __name__ == "__main__":
    main()
