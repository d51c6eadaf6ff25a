"""Photon Monte Carlo on the scene's own meshes: energy deposited per body, dose, and the
detector image split into primary and scattered photons.

Four parts meet in one short loop (:mod:`~xray_viz.montecarlo.loop`): the physics (xraylib's
cross sections and form factors, the samplers: :mod:`~xray_viz.montecarlo.physics`), the
geometry (a BVH and the primary engines' watertight crossings, the precedence of nested and
overlapping bodies: :mod:`~xray_viz.montecarlo.geometry`), the source
(:mod:`~xray_viz.montecarlo.sources`) and the tallies (:mod:`~xray_viz.montecarlo.tallies`).
Photons only: photoelectric absorption, incoherent (Klein-Nishina x S) and coherent
(Thomson x F^2) scattering; electrons and fluorescence deposit their energy on the spot
(valid to ~150 keV, as AAPM TG-195's photon codes assume); cut-off 1 keV.

A CT orbit is a transport per pose: ``transport(scene.replace(acquisition=acq), n)`` for each
acquisition of the orbit (:mod:`xray_viz.orbit`); the bodies' set-up is shared.

Examples
--------
>>> import dataclasses, xray_viz
>>> scene = xray_viz.load_scene("sphere")
>>> water = [dataclasses.replace(b, mu=None, material="Water, Liquid") for b in scene.bodies]
>>> result = xray_viz.transport(scene.replace(bodies=water), 2000, seed=1)
>>> sorted(result.images), result.images["primary"].shape
(['coherent', 'incoherent', 'multiple', 'primary'], (256, 256))
>>> b = result.balance
>>> abs(b["deposited"] + b["world"] + b["escaped"] + b["detector"] - b["emitted"]) < 1e-6
True
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["transport", "Transport", "prepare", "IMAGE_KEYS"]


def _world(scene):
    """``(material, density)`` of the world medium, ``(None, 0)`` for vacuum."""
    world = getattr(scene, "world", None)
    if not world:
        return None, 0.0
    from xray_viz.errors import MaterialError
    from xray_viz.physics.materials import check_material

    material = world.get("material")
    try:
        density = check_material(material, density=world.get("density"))
    except MaterialError as exc:
        raise MaterialError(f"[world] {exc}") from None
    return material, density


def _check_histories(histories) -> int:
    if isinstance(histories, bool) or not isinstance(histories, (int, np.integer)):
        try:
            ok = float(histories).is_integer()
        except (TypeError, ValueError):
            ok = False
        if not ok:
            raise SceneError(f"histories must be a whole number > 0, got {histories!r}")
    n = int(histories)
    if n <= 0:
        raise SceneError(f"histories must be > 0, got {n}: give the number of photons to "
                         "emit, e.g. 100000")
    return n


#: Points sampled in a body that partly overlaps another, for its region's volume.
OVERLAP_SAMPLES = 200_000


def _region_masses(scene, densities, bvh, rank_order) -> np.ndarray:
    """kg of each body's region: its volume less the bodies nested in it that win there
    (exact); a body partly overlapping another (their boxes meet, neither inside the other):
    its volume times the fraction of :data:`OVERLAP_SAMPLES` seeded points in it where it wins
    (the transport's own rule, :func:`~xray_viz.montecarlo.geometry.winners`)."""
    from xray_viz.meshes.repair import containers
    from xray_viz.montecarlo.geometry import winners

    bodies = list(scene.bodies)
    vol = np.array([abs(float(b.mesh.volume)) for b in bodies])      # mm3
    inside = containers([b.mesh for b in bodies])
    rank = np.asarray(scene.precedence)
    region = vol.copy()
    for a, outer in enumerate(inside):
        # a is carved out of the innermost body containing it that it outranks
        cands = [b for b in outer if rank[a] > rank[b]]
        if cands:
            inner_most = min(cands, key=lambda b: vol[b])
            region[inner_most] -= vol[a]
    bounds = np.array([b.mesh.bounds for b in bodies])
    rng = np.random.default_rng(20150)
    for a in range(len(bodies)):
        partial = [b for b in range(len(bodies)) if b != a and b not in inside[a]
                   and a not in inside[b]
                   and np.all(bounds[a, 0] < bounds[b, 1]) and np.all(bounds[b, 0] < bounds[a, 1])]
        if not partial:
            continue
        pts = rng.uniform(bounds[a, 0], bounds[a, 1], size=(OVERLAP_SAMPLES, 3))
        w = winners(pts, bvh.lo, bvh.hi, bvh.child, bvh.start, bvh.count, bvh.v0, bvh.v1,
                    bvh.v2, bvh.body, rank_order, len(bodies))
        mine = np.count_nonzero(w == a)               # where a wins: its region
        box = float(np.prod(bounds[a, 1] - bounds[a, 0]))
        region[a] = box * mine / len(pts)
    return region * 1e-3 * np.asarray(densities) * 1e-3                  # cm3 * g/cm3 -> kg


def prepare(scene, histories, *, seed: int = 0, batch: int | None = None) -> dict:
    """Everything the kernels need, as plain arrays (what a Dask worker receives).

    Raises
    ------
    SceneError
        Histories not > 0, no detector, a body given by ``mu`` only (the transport needs a
        material and its density).
    MaterialError
        An unknown world material.
    """
    from xray_viz.physics.materials import check_material
    from xray_viz.physics.spectra import source_spectrum
    from xray_viz.montecarlo.geometry import build_bvh
    from xray_viz.montecarlo.physics import CUTOFF_KEV, tables
    from xray_viz.montecarlo.sources import field

    from xray_viz.montecarlo.tallies import BATCH

    n = _check_histories(histories)
    batch = BATCH if batch is None else int(batch)
    if batch < 1:
        raise SceneError(f"batch must be >= 1 history, got {batch}")
    if getattr(scene, "detector", None) is None:
        raise SceneError("the scene has no detector: the transport emits into the field "
                         "the detector covers; add a [detector] table")
    seed = int(seed)
    if seed < 0:
        raise SceneError(f"seed must be >= 0, got {seed}")
    mats = []
    for body in scene.bodies:
        if body.material is None:
            raise SceneError(f"body {body.name!r} gives only 'mu': the transport needs its "
                             "'material' (and 'density' where the material has none)")
        mats.append((body.name, body.material, check_material(body.material,
                                                              density=body.density)))
    world_material, world_density = _world(scene)
    spectrum = source_spectrum(scene.source)
    keep = spectrum.energies >= CUTOFF_KEV
    energies = np.ascontiguousarray(spectrum.energies[keep])
    if len(energies) == 0:
        raise SceneError(f"every energy of the source is below the cut-off {CUTOFF_KEV} keV")
    weights = spectrum.weights[keep]
    cdf = np.cumsum(weights) / weights.sum()
    cdf[-1] = 1.0
    tab = tables([("world", world_material, world_density)] + mats,
                 e_max=float(energies.max()))
    tri = np.asarray(scene.triangles, float).reshape(-1, 3, 3)
    # kept on the bodies (every pose of an orbit, every call with the same meshes)
    bvh = scene.bodies.cached(("montecarlo", "bvh"),
                              lambda: build_bvh(tri, scene.triangle_body), limit=1)
    fa = field(scene.acquisition)
    f = scene.acquisition.frame
    w, h = f.shape
    corners = [fa[7:10] + a * fa[19] * fa[10:13] + b * fa[20] * fa[13:16]
               for a in (-1, 1) for b in (-1, 1)]
    pts = np.vstack([tri.reshape(-1, 3), np.array(corners), fa[0:3][None, :]])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * float(np.linalg.norm(hi - lo)) + 1.0
    rank = np.asarray(scene.precedence) if len(scene.bodies) else np.zeros(0, int)
    return {"histories": n, "seed": seed, "batch": batch, "field": fa, "energies": energies, "cdf": cdf,
            "world_lo": lo - pad, "world_hi": hi + pad, "bvh": bvh, "tables": tab,
            "rank_order": np.argsort(-rank, kind="stable").astype(np.int64),
            "n_regions": len(mats) + 1, "shape": (w, h),
            "names": [m[0] for m in mats], "densities": [m[2] for m in mats],
            "spectrum": spectrum}


def transport(scene, histories, *, seed=0, client=None, progress=None, interruptible=False,
              batch=None):
    """Transport ``histories`` photons from the scene's source through its bodies.

    Parameters
    ----------
    scene : Scene
    histories : int
        Photons emitted into the field the detector covers (one history each).
    seed : int
        The same seed gives the same numbers, bit for bit, serially or on any Dask cluster.
    client : distributed.Client, optional
        Run the groups of batches as Dask tasks (tallies added in group order on the client).
    progress : callable, optional
        ``progress(done, total)`` after each group, histories.
    interruptible : bool
        On Ctrl-C (KeyboardInterrupt) return the groups finished so far (their ``histories``,
        ``extra["interrupted"]`` true) instead of raising.
    batch : int, optional
        Histories per batch (one random stream each; default
        :data:`~xray_viz.montecarlo.tallies.BATCH`): the numbers depend on it and on the seed,
        never on the threads or workers.

    Returns
    -------
    Transport
        :class:`Transport`.
    """
    from xray_viz import _threads
    from xray_viz.montecarlo.tallies import GROUP, Tallies, n_groups, run_group

    p = prepare(scene, histories, seed=seed, batch=batch)
    n = p["histories"]
    total = Tallies.zeros(p["n_regions"], p["shape"])
    groups = n_groups(n, p["batch"])
    done = 0
    futures = []
    interrupted = False
    try:
        if client is None:
            threads = max(1, _threads.count())
            parts = (run_group(p, g, threads=threads) for g in range(groups))
        else:
            [shared] = client.scatter([p], broadcast=True)
            futures = [client.submit(run_group, shared, g, pure=False) for g in range(groups)]
            parts = (fut.result() for fut in futures)
        for g, part in enumerate(parts):
            total.add(part)                       # in group order: the same bits anywhere
            done = min(n, (g + 1) * p["batch"] * GROUP)
            if progress is not None:
                progress(done, n)
    except KeyboardInterrupt:
        if not interruptible or done == 0:
            raise
        interrupted = True
    finally:
        for fut in futures:
            fut.cancel()
    masses = photons = None
    spectrum = p["spectrum"]
    mas = getattr(scene.source, "mas", None)
    if mas is not None and spectrum.fluence_per_mas is not None and len(p["names"]):
        from xray_viz.montecarlo.sources import solid_angle

        masses = _region_masses(scene, p["densities"], p["bvh"], p["rank_order"])
        # photons/mm2 at 1 m per mAs -> photons per sr: x (1000 mm)^2
        photons = spectrum.fluence_per_mas * 1e6 * solid_angle(scene.acquisition) * mas
    out = _result(total, histories=done, names=p["names"], seed=p["seed"], masses=masses,
                 photons=photons)
    out.extra["interrupted"] = interrupted
    out.extra["requested"] = n
    return out


def _mean_error(total, total_sq, n):
    mean = total / n
    var = np.maximum(total_sq / n - mean * mean, 0.0)
    return mean, np.sqrt(var / max(n - 1, 1))


@dataclass
class Transport:
    """The result of :func:`xray_viz.transport`: energies in eV per history, with standard
    errors.

    Attributes
    ----------
    histories : int
        Photons emitted into the field.
    energy, energy_error : dict of str to float
        Energy deposited in each body's region (where it wins the precedence), eV per history.
    images, image_errors : dict of str to (H, W) float
        ``"primary"``, ``"incoherent"`` (one incoherent scattering), ``"coherent"`` (one
        coherent scattering), ``"multiple"``: the energy of the photons reaching each pixel,
        eV per history. This is the energy *incident* on the detector plane: the scene's
        detector model is not applied (no ``response``, ``scintillator`` absorption
        efficiency, blur, gain or noise). To compare with a rendered image of an ideal
        energy-integrating detector, divide the primary image by the energy each pixel would
        receive in vacuum (:func:`xray_viz.render`'s ``intensity`` is that ratio).
    balance : dict of str to float
        eV per history: ``emitted``, ``deposited`` (bodies), ``world`` (the world medium),
        ``escaped``, ``detector``; ``emitted`` = the others' sum, to rounding.
    balance_error : dict of str to float
        Standard errors of ``balance["deposited"]`` (all the bodies together: each history's
        sum, so the regions' correlation counts) and ``balance["detector"]``.
    dose, dose_error : dict of str to float or None
        Gy per body with ``[source] mas`` and a SpekPy tube spectrum (its output per mAs gives
        the photons emitted into the field): the region's energy over its mass, from the
        body's volume and density less the bodies nested in it that win there (exact), or, for
        a body partly overlapping another, from 200,000 seeded points in its box (~0.2 %);
        None without ``mas`` or with a CSV or monochromatic spectrum.
    seed : int
    extra : dict
        ``interrupted`` (bool) and ``requested`` (histories asked for).
    """

    histories: int
    energy: dict
    energy_error: dict
    images: dict
    image_errors: dict
    balance: dict
    dose: dict | None = None
    dose_error: dict | None = None
    seed: int = 0
    balance_error: dict = field(default_factory=dict)
    extra: dict = field(default_factory=dict)

    def table(self) -> list[dict]:
        """One row per body: name, eV per history, its standard error, Gy and its error."""
        rows = []
        for name in self.energy:
            rows.append({"body": name, "energy_eV_per_history": self.energy[name],
                         "energy_error": self.energy_error[name],
                         "dose_Gy": None if self.dose is None else self.dose[name],
                         "dose_error": None if self.dose is None else self.dose_error[name]})
        return rows


#: The detector images of a :class:`Transport`, in the tallies' order.
IMAGE_KEYS = ("primary", "incoherent", "coherent", "multiple")


def _result(tallies, *, histories: int, names, seed: int, masses=None,
            photons=None) -> Transport:
    """A :class:`Transport` from summed tallies (keV) of ``histories`` histories
    (:class:`~xray_viz.montecarlo.tallies.Tallies`)."""
    n = int(histories)
    ev = 1000.0
    mean, err = _mean_error(tallies.dep[0], tallies.dep[1], n)
    energy = {name: float(mean[1 + k] * ev) for k, name in enumerate(names)}
    energy_error = {name: float(err[1 + k] * ev) for k, name in enumerate(names)}
    im, ie = _mean_error(tallies.img, tallies.img_sq, n)
    images = {key: im[k] * ev for k, key in enumerate(IMAGE_KEYS)}
    image_errors = {key: ie[k] * ev for k, key in enumerate(IMAGE_KEYS)}
    tot = tallies.totals
    _, dep_err = _mean_error(float(tallies.dep[0, 1:].sum()), tot[6], n)
    _, det_err = _mean_error(tot[1], tot[2], n)
    balance_error = {"deposited": float(dep_err * ev), "detector": float(det_err * ev)}
    balance = {"emitted": tot[0] / n * ev, "deposited": float(tallies.dep[0, 1:].sum()) / n * ev,
               "world": tallies.dep[0, 0] / n * ev, "escaped": tot[3] / n * ev,
               "detector": tot[1] / n * ev}
    dose = dose_error = None
    if masses is not None and photons is not None:
        joule = 1.602176634e-19 * photons
        dose = {nm: energy[nm] * joule / masses[k] for k, nm in enumerate(names)}
        dose_error = {nm: energy_error[nm] * joule / masses[k] for k, nm in enumerate(names)}
    return Transport(histories=n, energy=energy, energy_error=energy_error, images=images,
                     image_errors=image_errors, balance={k: float(v) for k, v in balance.items()},
                     dose=dose, dose_error=dose_error, seed=seed,
                     balance_error=balance_error)
