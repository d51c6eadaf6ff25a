"""AAPM TG-195 cases as xray_viz scenes (tests/data/tg195/, README there)."""

from __future__ import annotations

import csv
import json

import numpy as np
import trimesh

from helpers import REPO

DATA = REPO / "tests" / "data" / "tg195"


def cases() -> dict:
    return {c["id"]: c for c in json.loads((DATA / "cases.json").read_text())["cases"]}


def materials() -> dict:
    return json.loads((DATA / "materials.json").read_text())["materials"]


def material(name: str) -> tuple[dict, float]:
    m = materials()[name]
    return dict(m["weight_fractions"]), float(m["density_g_cm3"])


def results() -> list[dict]:
    with open(DATA / "results.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def reference(case: str, volume: str, source: str) -> dict:
    for row in results():
        if row["case"] == case and row["volume"] == volume and row["source"] == source:
            return row
    raise KeyError((case, volume, source))


def spectrum(label: str):
    from xray_viz.physics.spectra import Spectrum

    name = {"120 kVp": "spectrum_120kVp_WAl.csv", "100 kVp": "spectrum_100kVp_WAl.csv",
            "30 kVp": "spectrum_30kVp_MoMo.csv"}[label]
    data = np.loadtxt(DATA / name, delimiter=",", skiprows=1)
    keep = data[:, 1] > 0
    return Spectrum(data[keep, 0], data[keep, 1], description=f"TG-195 {label}")


def box(center, size) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=size)
    m.apply_translation(center)
    return m


def case2_scene(source_label: str = "56.4 keV", *, pixels: int = 39):
    """Case 2, radiography: the soft-tissue slab with its nine VOIs as nested bodies of the same
    material (the slab's own region + the VOIs = the total body), air around, the detector
    covering the 390 x 390 mm field at z = 1800 mm."""
    from xray_viz.scene import Body, Detector, Scene, Source

    case = cases()["2"]
    tissue, rho = material("Soft tissue")
    air, rho_air = material("Air")
    bodies = [Body(name="phantom", mesh=box(case["objects"][0]["center"],
                                            case["objects"][0]["size"]),
                   material=tissue, density=rho)]
    for voi in case["vois"][1:]:
        bodies.append(Body(name=voi["name"], mesh=box(voi["center"], voi["size"]),
                           material=tissue, density=rho))
    src = next(s for s in case["sources"] if s["label"] == source_label)
    if "energy_keV" in src:
        source = Source(position=[0, 0, 0], energy=src["energy_keV"])
    else:
        source = Source(position=[0, 0, 0], energy=None, spectrum=spectrum(source_label))
    detector = Detector(center=[0, 0, 1800], up=[0, 1, 0], shape=(pixels, pixels),
                        pitch=(390.0 / pixels, 390.0 / pixels))
    return Scene(source=source, detector=detector, bodies=tuple(bodies),
                 world={"material": air, "density": rho_air})


def total_body(result) -> tuple[float, float]:
    """Case 2's total body: the energy (eV/history) in all the bodies together (the slab's own
    region and the nine VOIs) and its standard error (from each history's sum)."""
    return result.balance["deposited"], result.balance_error["deposited"]


def case1_kermas(label: str) -> dict:
    """Case 1, narrow beam: air kerma (keV/g per history / 100, TG-195's unit) on the 5 mm disc
    at 1 m behind each filter, from the transport's own tables (primary photons: the disc
    sees the source through the filter and 1 m of air)."""
    from xray_viz.montecarlo import physics as P

    case = cases()["1"]
    al, rho_al = material("Aluminium")
    air, rho_air = material("Air")
    src = next(s for s in case["sources"] if s["label"] == label)
    if "energy_keV" in src:
        energies, weights = np.array([src["energy_keV"]]), np.array([1.0])
        # scored in the 0.5 keV bin that holds it, just below the edge (29.75, 99.75 keV)
        centres = np.ceil(energies / 0.5) * 0.5 - 0.25
    else:
        s = spectrum(label)
        energies, weights, centres = s.energies, s.weights, s.energies
    t = P.tables([("air", air, rho_air), ("al", al, rho_al)], e_max=float(energies.max()))

    def mu(m):
        return np.array([sum(P.mu_lookup(t.mu[m], t.ln_e0, t.d_ln_e, e)) for e in energies])

    table = np.loadtxt(DATA / "air_mu_en_rho.csv", delimiter=",", skiprows=1)
    mu_en = np.interp(centres, table[:, 0], table[:, 1])
    disc_cm2 = np.pi * 0.5 ** 2
    out = {}
    for name, thick in case["filter_thickness_t_mm"][label].items():
        transmitted = np.exp(-mu(1) * thick - mu(0) * (1000.0 - thick))
        out[name] = float((weights * centres * mu_en * transmitted).sum() / disc_cm2 / 100.0)
    return out


def half_cylinder(center, radius, length, *, segments: int = 512) -> trimesh.Trimesh:
    """The half of a z-axis cylinder with x >= center x (TG-195 case 3's breast), closed by its
    flat face; the arc as ``segments`` chords."""
    a = np.linspace(-np.pi / 2, np.pi / 2, segments + 1)
    ring = np.column_stack([radius * np.cos(a), radius * np.sin(a)])
    ring[0, 0] = ring[-1, 0] = 0.0                 # exactly on the flat face
    n = len(ring)
    lo = np.column_stack([ring, np.full(n, -length / 2)])
    hi = np.column_stack([ring, np.full(n, length / 2)])
    v = np.vstack([lo, hi]) + np.asarray(center, float)
    faces = []
    for i in range(n - 1):                          # the curved side
        faces += [[i, i + 1, n + i + 1], [i, n + i + 1, n + i]]
    faces += [[n - 1, 0, n], [n - 1, n, 2 * n - 1]]  # the flat face
    # the caps in strips across y (vertex i and n - 1 - i are mirror images): thin boxes for
    # the BVH, where fans from one vertex would all overlap
    for i in range((n - 1) // 2):
        j, k = n - 1 - i, n - 2 - i
        quads = [[i, i + 1, k, j]] if i + 1 != k else [[i, i + 1, j]]
        for q in quads:
            tris = [[q[0], q[1], q[2]], [q[0], q[2], q[3]]] if len(q) == 4 else [q]
            for t in tris:
                a, b, c = (ring[t[0]], ring[t[1]], ring[t[2]])
                if (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]) > 0:
                    t = [t[0], t[2], t[1]]            # the bottom faces -z
                faces += [t, [n + t[0], n + t[2], n + t[1]]]
    mesh = trimesh.Trimesh(v, np.array(faces), process=True)
    trimesh.repair.fix_normals(mesh)
    return mesh


def case3_scene(source_label: str = "16.8 keV", *, pixels: tuple = (28, 52)):
    """Case 3, radiography: the breast (20 % glandular) in its 2 mm skin, the seven VOIs as
    nested bodies of the breast's material, the PMMA paddle and support, the water chest-wall
    block, air around; the detector covering the 140 x 260 mm half field at z = -40 mm, the
    central ray down the chest-wall plane x = 0."""
    from xray_viz.scene import Body, Detector, Scene, Source

    case = cases()["3"]
    objects = {o["name"]: o for o in case["objects"]}
    air, rho_air = material("Air")
    bodies = []
    for name, o in objects.items():
        if "receptor" in name:
            continue
        mat, rho = material(o["material"])
        mesh = (box(o["center"], o["size"]) if o["shape"] == "box"
                else half_cylinder(o["center"], o["radius"], o["length"]))
        bodies.append(Body(name=name, mesh=mesh, material=mat, density=rho))
    mat, rho = material("Breast 20% glandular (case 3)")
    for voi in case["vois"][1:]:
        bodies.append(Body(name=voi["name"], mesh=box(voi["center"], voi["size"]),
                           material=mat, density=rho))
    src = next(s for s in case["sources"] if s["label"] == source_label)
    position = case["modes"]["radiography"]["position"]
    if "energy_keV" in src:
        source = Source(position=position, energy=src["energy_keV"])
    else:
        source = Source(position=position, energy=None, spectrum=spectrum(source_label))
    w, h = pixels
    probe = Detector(center=[0, 0, -40], up=[0, 1, 0], shape=(w, h), pitch=(140 / w, 260 / h))
    ho = Scene(source=source, detector=probe).acquisition.frame.ho
    detector = Detector(center=[0, 0, -40], up=[0, 1, 0], shape=(w, h),
                        pitch=(140 / w, 260 / h), offset=(70.0 * float(np.sign(ho[0])), 0.0))
    return Scene(source=source, detector=detector, bodies=tuple(bodies),
                 world={"material": air, "density": rho_air})


def case3_total_body(result) -> tuple[float, float]:
    """The breast tissue inside the skin with its VOIs (eV/history, error)."""
    names = ["breast tissue"] + [f"VOI {k}" for k in range(1, 8)]
    e = sum(result.energy[n] for n in names)
    return e, float(np.sqrt(sum(result.energy_error[n] ** 2 for n in names)))
