"""Photon Monte Carlo on the scene's own meshes and voxel volumes: energy deposited per body
(and per class of a volume), dose, and the detector image split into primary and scattered
photons.

Four parts meet in one short loop (:mod:`~xray_viz.montecarlo.loop`): the physics (xraylib's
cross sections and form factors, the samplers: :mod:`~xray_viz.montecarlo.physics`), the
geometry (a BVH and the primary engines' watertight crossings, the precedence of nested and
overlapping bodies: :mod:`~xray_viz.montecarlo.geometry`), the source
(:mod:`~xray_viz.montecarlo.sources`) and the tallies (:mod:`~xray_viz.montecarlo.tallies`).
Photons only: photoelectric absorption, incoherent (Klein-Nishina x S) and coherent
(Thomson x F^2) scattering; electrons and fluorescence deposit their energy on the spot
(valid to ~150 keV, as AAPM TG-195's photon codes assume); cut-off 1 keV.

Voxel volumes (``scene.volumes``: ``[[ct]]`` / ``[[labels]]`` with ``trace = "voxels"``) are
crossed by Woodcock (delta) tracking, as MC-GPU does: inside a grid's box a photon flies with
the meshes' ``mu`` plus the volume's majorant (the largest weight x ``mu`` over its classes,
per energy), and a collision is real with probability ``mu(point) / mu_max``, else the photon
flies on unchanged. Chosen over exact voxel stepping because a flight then costs one voxel
look-up per tentative collision instead of one step per voxel crossed (a CT's photons cross
hundreds of voxels between interactions), and the meshes' crossings, the detector and the
world's box stay the only boundaries; it is exact (no bias), the price being virtual
collisions where the volume is much thinner than its densest voxel (lung next to bone). Each
voxel's material and density are the voxel render's own (:class:`~xray_viz.volume.
VoxelVolume`'s classes and weights: one home); a mesh body that displaces the volume
(``xray_viz.volume.displacers``: an implant) replaces the voxels wherever a photon is inside
it, whatever its precedence; a mesh around the whole volume (a tank) adds to the voxels, and
the world medium is replaced by every voxel of a class - all as the render resolves them.

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

__all__ = ["transport", "Transport", "prepare", "flat_signal", "IMAGE_KEYS"]


def _world(scene):
    """``(material, density)`` of the world medium, ``(None, 0)`` for vacuum."""
    world = scene.world
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


#: Most histories whose tracks :func:`transport` records (``tracks=``).
MAX_TRACKS = 10_000

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
        w = winners(pts, bvh, rank_order, len(bodies))
        mine = np.count_nonzero(w == a)               # where a wins: its region
        box = float(np.prod(bounds[a, 1] - bounds[a, 0]))
        region[a] = box * mine / len(pts)
    return region * 1e-3 * np.asarray(densities) * 1e-3                  # cm3 * g/cm3 -> kg


def _voxel_problem(scene, n_bodies: int) -> dict:
    """The voxel volumes as the kernel reads them (``run_batch``'s volume arguments) and the
    classes as regions: ``materials`` ``(name, material, density)`` for the tables, after
    the bodies'; the majorants are filled in by :func:`_majorants` once the tables exist."""
    from xray_viz.physics.materials import check_material
    from xray_viz.tracing.voxels import inverse_affine
    from xray_viz.volume import displacers

    volumes = tuple(scene.volumes)
    mats, region0, inv, dims, flat_c, flat_w, wmax = [], [], [], [], [], [], []
    displace = np.zeros((len(volumes), max(n_bodies, 1)), np.bool_)
    for v, vol in enumerate(volumes):
        if vol.interpolation != "nearest":
            raise SceneError(f"volume {vol.name!r}: the transport traces voxels as nearest-voxel "
                             f"values, not interpolation = {vol.interpolation!r}; remove the "
                             "key (or set \"nearest\") for a transport")
        region0.append(n_bodies + len(mats))
        for m in vol.materials:
            if m.material is None:
                raise SceneError(f"volume {vol.name!r}: class {m.name!r} gives only 'mu': the "
                                 "transport needs its 'material' (and 'density' where the "
                                 "material has none)")
            mats.append((m.name, m.material, check_material(m.material, density=m.density)))
        for b in displacers(vol, scene.bodies, warn=False):
            displace[v, b] = True
        inv.append(inverse_affine(vol.affine))
        dims.append(vol.shape)
        c = np.ascontiguousarray(vol.classes).reshape(-1)
        w = np.ascontiguousarray(vol.weights).reshape(-1)
        flat_c.append(c)
        flat_w.append(w)
        # each class's largest weight (its densest voxel), for the majorant
        wmax.append(np.array([float(w[c == k].max(initial=0.0))
                              for k in range(1, len(vol.materials) + 1)]))
    start = np.cumsum([0] + [len(c) for c in flat_c[:-1]]).astype(np.int64)
    if len(flat_c) == 1:
        classes, weights = flat_c[0], flat_w[0]            # the grid itself, no copy
    elif flat_c:
        classes = np.concatenate(flat_c)
        weights = np.concatenate([w.astype(np.float64) for w in flat_w])
    else:
        classes, weights = np.zeros(0, np.uint8), np.zeros(0)
    return {"inv": np.array(inv, np.float64).reshape(-1, 3, 4),
            "dims": np.array(dims, np.int64).reshape(-1, 3), "start": start,
            "classes": classes, "weights": weights,
            "region0": np.array(region0, np.int64), "displace": displace,
            "majorant": np.zeros((len(volumes), 3, 2)), "wmax": wmax,
            "materials": mats}


def _majorants(vox: dict, mu: np.ndarray) -> None:
    """Each volume's majorant on the tables' energy grid: the largest over its classes of
    the class's largest weight x its total ``mu``, widened by 1e-9 (row 0 of
    ``vox["majorant"]``). Linear in ``ln E`` between grid points as ``mu`` is, so it bounds
    every voxel's ``mu`` at every energy."""
    vox["majorant"] = np.zeros((len(vox["region0"]), 3, mu.shape[2]))
    for v, r0 in enumerate(vox["region0"]):
        top = vox["wmax"][v]
        rows = mu[1 + r0:1 + r0 + len(top)].sum(axis=1)          # (classes, N)
        if len(top):
            vox["majorant"][v, 0] = (top[:, None] * rows).max(axis=0) * (1.0 + 1e-9)


def _class_masses(scene, densities, bvh) -> np.ndarray:
    """kg of each voxel class: the sum over its voxels of voxel volume x weight x the class's
    table density, less the voxels whose centre lies inside a mesh body that displaces the
    volume (the transport's rule; exact to the voxels cut by the mesh's surface)."""
    from xray_viz.montecarlo.geometry import winners
    from xray_viz.volume import displacers

    out = []
    k = 0
    for vol in scene.volumes:
        voxel_cm3 = abs(float(np.linalg.det(vol.affine[:3, :3]))) * 1e-3
        c = np.asarray(vol.classes)
        w = np.asarray(vol.weights, np.float64)
        n = len(vol.materials)
        keep = np.ones(c.shape, bool)
        which = displacers(vol, scene.bodies, warn=False)
        if which:
            inv = np.linalg.inv(vol.affine)
            box = np.array([scene.bodies[b].mesh.bounds for b in which])
            lo_w, hi_w = box[:, 0].min(axis=0), box[:, 1].max(axis=0)
            corners = np.array([[x, y, z] for x in (lo_w[0], hi_w[0])
                                for y in (lo_w[1], hi_w[1]) for z in (lo_w[2], hi_w[2])])
            idx = corners @ inv[:3, :3].T + inv[:3, 3]
            i0 = np.clip(np.floor(idx.min(axis=0)).astype(int), 0, np.array(c.shape) - 1)
            i1 = np.clip(np.ceil(idx.max(axis=0)).astype(int) + 1, 1, np.array(c.shape))
            grid = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(i0, i1)],
                                        indexing="ij"), axis=-1).reshape(-1, 3)
            pts = grid @ vol.affine[:3, :3].T + vol.affine[:3, 3]
            order = np.array(which, np.int64)            # "inside any displacer"
            got = winners(pts, bvh, order, len(scene.bodies))
            inside = grid[got >= 0]
            keep[inside[:, 0], inside[:, 1], inside[:, 2]] = False
        sums = np.bincount(c[keep].ravel(), weights=w[keep].ravel(), minlength=n + 1)[1:]
        for j in range(n):
            out.append(sums[j] * voxel_cm3 * densities[k + j] * 1e-3)   # g -> kg
        k += n
    return np.array(out, float)


def prepare(scene, histories, *, seed: int = 0, batch: int | None = None,
            tracks: int = 0) -> dict:
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
    # voxel volumes: their classes are regions after the bodies'
    vox = _voxel_problem(scene, len(mats))
    tracks = int(tracks)
    if not 0 <= tracks <= MAX_TRACKS:
        raise SceneError(f"tracks must be between 0 and {MAX_TRACKS}, got {tracks}")
    world_material, world_density = _world(scene)
    spectrum = source_spectrum(scene.source)
    keep = spectrum.energies >= CUTOFF_KEV
    energies = np.ascontiguousarray(spectrum.energies[keep])
    if len(energies) == 0:
        raise SceneError(f"every energy of the source is below the cut-off {CUTOFF_KEV} keV")
    weights = spectrum.weights[keep]
    cdf = np.cumsum(weights) / weights.sum()
    cdf[-1] = 1.0
    tab = tables([("world", world_material, world_density)] + mats + vox["materials"],
                 e_max=float(energies.max()))
    _majorants(vox, tab.mu)
    tri = np.asarray(scene.triangles, float).reshape(-1, 3, 3)
    # kept on the bodies (every pose of an orbit, every call with the same meshes)
    bvh = scene.bodies.cached(("montecarlo", "bvh"),
                              lambda: build_bvh(tri, scene.triangle_body), limit=1)
    fa = field(scene.acquisition)
    f = scene.acquisition.frame
    w, h = f.shape
    corners = [fa[7:10] + a * fa[19] * fa[10:13] + b * fa[20] * fa[13:16]
               for a in (-1, 1) for b in (-1, 1)]
    pts = np.vstack([tri.reshape(-1, 3), np.array(corners), fa[0:3][None, :]]
                    + [v.corners for v in scene.volumes])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * float(np.linalg.norm(hi - lo)) + 1.0
    rank = np.asarray(scene.precedence) if len(scene.bodies) else np.zeros(0, int)
    out = {"histories": n, "seed": seed, "batch": batch, "field": fa, "energies": energies, "cdf": cdf,
            "world_lo": lo - pad, "world_hi": hi + pad, "bvh": bvh, "tables": tab,
            "rank_order": np.argsort(-rank, kind="stable").astype(np.int64),
            "n_regions": len(mats) + len(vox["materials"]) + 1, "shape": (w, h),
            "names": [m[0] for m in mats], "densities": [m[2] for m in mats],
            "spectrum": spectrum,
            # voxel volumes (their classes' names and densities follow the bodies') and tracks
            "voxels": vox, "tracks": tracks,
            "class_names": [m[0] for m in vox["materials"]],
            "class_densities": [m[2] for m in vox["materials"]]}
    # the detector's reading (issue 39): its response, scintillator and anti-scatter grid
    out["response"], out["grid"] = reading_tables(scene.detector, float(energies.max()))
    return out


#: Spacing (keV) of the energy table of the detector's reading in the transport's loop.
READING_STEP_KEV = 0.05


def reading_tables(detector, e_max: float):
    """``(resp, gpar)``: the detector's reading as :func:`~xray_viz.montecarlo.loop.run_batch`
    takes it.

    ``resp`` (3, n): per energy ``0, step, 2 step, ... >= e_max`` keV, the score ``q(E)`` of
    a photon (``E eta(E)`` energy-integrating, ``eta(E) / 1000`` counting, so that the
    images, kept in eV, are photons; ``E (mu_en/rho)_air(E) eta(E)`` kerma; ``eta`` the
    scintillator's absorption efficiency), then the grid's strip and interspace attenuation
    (1/mm); ``gpar``: ``[flag, strip thickness, period, strip height, focus distance, step]``,
    flag -1 for the bare energy (an ideal energy-integrating detector without a grid: the
    images of issue 38, bit for bit), 0 for a response without a grid, 1 with a grid.
    """
    from xray_viz.physics.detector import absorption_efficiency

    grid, response, scint = detector.grid, detector.response, detector.scintillator
    step = READING_STEP_KEV
    if grid is None and scint is None and response == "energy":
        return np.zeros((3, 2)), np.array([-1.0, 0.0, 1.0, 0.0, 1.0, step])
    e = np.arange(int(np.ceil(e_max / step)) + 2) * step
    e_eval = np.maximum(e, 1.0)                     # below the cut-off no photon scores
    q = absorption_efficiency(scint, e_eval)
    if response == "energy":
        q = q * e
    elif response == "kerma":
        from xray_viz.physics._air import air_mass_energy_absorption

        q = q * e * air_mass_energy_absorption(e_eval)
    else:                                           # counting: one photon, eV -> photons
        q = q / 1000.0
    resp = np.zeros((3, len(e)))
    resp[0] = q
    if grid is None:
        return resp, np.array([0.0, 0.0, 1.0, 0.0, 1.0, step])
    resp[1], resp[2] = grid.attenuation(e_eval)
    return resp, np.array([1.0, grid.strip_thickness, grid.period, grid.strip_height,
                           grid.focus_distance, step])


def transport(scene, histories, *, seed=0, client=None, progress=None, interruptible=False,
              batch=None, tracks=0):
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
    tracks : int
        Record the paths of the first ``tracks`` histories (at most :data:`MAX_TRACKS`) in
        :attr:`Transport.tracks`; every other number is the same, bit for bit, with or
        without them.

    Returns
    -------
    Transport
        :class:`Transport`.
    """
    from xray_viz import _threads
    from xray_viz.montecarlo.tallies import GROUP, Tallies, n_groups, run_group

    p = prepare(scene, histories, seed=seed, batch=batch, tracks=tracks)
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
    mas = scene.source.mas
    names = p["names"] + p["class_names"]            # the bodies, then the volumes' classes
    if mas is not None and spectrum.fluence_per_mas is not None and len(names):
        from xray_viz.montecarlo.sources import solid_angle

        masses = np.concatenate([
            _region_masses(scene, p["densities"], p["bvh"], p["rank_order"])
            if len(p["names"]) else np.zeros(0),
            _class_masses(scene, p["class_densities"], p["bvh"])])
        # photons/mm2 at 1 m per mAs -> photons per sr: x (1000 mm)^2
        photons = spectrum.fluence_per_mas * 1e6 * solid_angle(scene.acquisition) * mas
    out = _result(total, histories=done, names=names, seed=p["seed"], masses=masses,
                 photons=photons)
    out.tracks = total.tracks
    out.extra["interrupted"] = interrupted
    out.extra["requested"] = n
    return out


def flat_signal(scene) -> np.ndarray:
    """(H, W) per history: what each pixel of the transport's detector images would read
    with no bodies and no world medium (the expected value, no Monte Carlo): its share of
    the field (:func:`~xray_viz.montecarlo.sources.pixel_shares`) times the mean reading of
    a photon the source emits above the cut-off, through the same detector response and
    anti-scatter grid as the images (:func:`reading_tables`; for an ideal energy-integrating
    detector without a grid, the mean energy, eV). ``Transport.images[k] /
    flat_signal(scene)`` is then in the units of a render's ``intensity / I0``: the primary
    image's ratio is the transmission, the scattered images' sum the scatter relative to the
    flat field.

    With a grid each pixel's primary direction (from the source through 8 points across the
    pixel, its middle along the strips) gives its grid transmission, the mean of the 8:
    where the source is not at the grid's focus the edges are cut off, as the transport's
    photons are.

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")                     # 60 keV
    >>> flat = flat_signal(scene)
    >>> flat.shape, round(float(flat.sum()), 6)                   # every photon, 60 keV
    ((256, 256), 60000.0)
    """
    from xray_viz.montecarlo.physics import CUTOFF_KEV
    from xray_viz.montecarlo.sources import pixel_shares
    from xray_viz.physics.spectra import source_spectrum

    if getattr(scene, "detector", None) is None:
        raise SceneError("the scene has no detector: add a [detector] table")
    spectrum = source_spectrum(scene.source)
    keep = spectrum.energies >= CUTOFF_KEV
    w = spectrum.weights[keep]
    energies = spectrum.energies[keep]
    resp, gpar = reading_tables(scene.detector, float(energies.max()))
    if gpar[0] < 0:
        mean_kev = float(w @ energies / w.sum())
        return pixel_shares(scene.acquisition) * (mean_kev * 1000.0)
    grid_e = np.arange(resp.shape[1]) * gpar[5]
    q = np.interp(energies, grid_e, resp[0]) * w / w.sum()          # (K,)
    if gpar[0] == 0:
        return pixel_shares(scene.acquisition) * (float(q.sum()) * 1000.0)
    return pixel_shares(scene.acquisition) * (_grid_levels(scene, energies, q, resp, gpar)
                                              * 1000.0)


def _grid_levels(scene, energies, q, resp, gpar, *, table=None) -> np.ndarray:
    """(H, W): ``sum_k q_k T_grid(E_k, pixel)``, the grid's transmission of each pixel's
    primary photons (mean over 8 points across the pixel), with the tables of the loop.

    ``table``: interpolate in a table over ``(t, s)`` (:data:`GRID_TABLE_NODES`) instead of
    evaluating every point at every energy; default when the detector has more points than
    the table (within ~1e-5 of the direct sum: tests/montecarlo/test_transport_grid.py)."""
    from xray_viz.montecarlo.sources import field
    from xray_viz.physics.grid import PeriodGeometry

    fa = field(scene.acquisition)
    grid_e = np.arange(resp.shape[1]) * gpar[5]
    mus = np.interp(energies, grid_e, resp[1])
    mui = np.interp(energies, grid_e, resp[2])
    f = scene.acquisition.frame
    (w, h), (pu, pv) = f.shape, f.pitch
    sub = 8
    a = (np.arange(w * sub) + 0.5) * (pu / sub) - 0.5 * w * pu          # across (ho), mm
    b = 0.5 * h * pv - (np.arange(h) + 0.5) * pv                       # rows, top first
    middle, ho, ve, normal = fa[7:10], fa[10:13], fa[13:16], fa[16:19]
    if fa[23] > 0:
        d = np.broadcast_to(fa[3:6], (h, w * sub, 3))
    else:
        d = (middle + a[None, :, None] * ho + b[:, None, None] * ve) - fa[0:3]
    dn = np.abs(d @ normal)
    t = (d @ ho) / dn - a[None, :] / gpar[4]
    s = (d @ ve) / dn

    def levels_at(tt, ss):
        geometry = PeriodGeometry(tt, ss, d=gpar[1], period=gpar[2], h=gpar[3])
        out = np.zeros(geometry.length.shape)
        for k in range(len(energies)):
            out += q[k] * geometry.mean(mus[k], mui[k])
        return out

    if table is None:
        table = t.size > GRID_TABLE_NODES[0] * GRID_TABLE_NODES[1]
    if not table:
        levels = levels_at(t, s)
    else:
        # a detector of many pixels: the weighted transmission on a (t, s) table, linear in t
        # (t = 0, its kink, a node) and in s (smooth: the path length), then interpolated
        t_nodes = np.linspace(t.min(), t.max(), GRID_TABLE_NODES[0])
        if t_nodes[0] < 0 < t_nodes[-1]:
            t_nodes = np.union1d(t_nodes, [0.0])
        s_nodes = np.linspace(s.min(), s.max(), GRID_TABLE_NODES[1])
        values = levels_at(t_nodes[None, :], s_nodes[:, None])           # (ns, nt)
        at_s = np.stack([np.interp(t, t_nodes, row) for row in values])  # (ns, h, w sub)
        j = np.clip(np.searchsorted(s_nodes, s) - 1, 0, len(s_nodes) - 2)
        span = s_nodes[j + 1] - s_nodes[j]
        frac = np.where(span > 0, (s - s_nodes[j]) / np.where(span > 0, span, 1.0), 0.0)
        lo = np.take_along_axis(at_s, j[None], axis=0)[0]
        hi = np.take_along_axis(at_s, (j + 1)[None], axis=0)[0]
        levels = lo + frac * (hi - lo)
    return levels.reshape(h, w, sub).mean(axis=2)


#: Nodes ``(t, s)`` of :func:`_grid_levels`' table, used when a detector has more points.
GRID_TABLE_NODES = (2049, 33)


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
        coherent scattering), ``"multiple"``: the detector's reading of the photons
        reaching each pixel, per history, through its response and anti-scatter grid: each
        photon of energy ``E`` scores ``q(E) T_grid(E, angle)`` (:func:`reading_tables`),
        ``q`` = ``E`` (eV) for the energy-integrating response, 1 (photons) counting,
        ``E (mu_en/rho)_air`` (eV cm2/g) kerma, times the scintillator's absorption
        efficiency; ``T_grid`` the grid's transmission at the photon's angle across its
        strips from their focused direction (:class:`~xray_viz.physics.grid.Grid`). Without a
        grid or scintillator an energy response reads the energy incident on the detector
        plane, eV per history. Blur, gain and noise are not applied. Divide by
        :func:`flat_signal` (the same reading in vacuum) for a render's ``intensity / I0``.
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
    tracks : list of (ndarray, str)
        With ``transport(..., tracks=N)``: the first N histories' paths in history order,
        each ``(vertices, end)``: ``vertices`` (k, 3) mm, the source point, each real
        interaction (photoelectric, incoherent, coherent; not the surface crossings nor the
        virtual collisions in a voxel volume) and where it ended; ``end`` one of
        ``"primary"`` (reached the detector unscattered), ``"scattered"`` (reached it after
        one or more interactions), ``"escaped"`` (left the world's box) and ``"absorbed"``
        (photoelectric absorption, or below the cut-off). A track of more than
        :data:`~xray_viz.montecarlo.tallies.TRACK_VERTICES` vertices keeps its first ones
        and its end. Empty otherwise.

    Notes
    -----
    A scene's voxel volumes (``scene.volumes``: ``[[ct]]`` or ``[[labels]]`` traced as
    voxels) score one entry per class under the names of the render's path-length columns
    (``<volume>_<class>``), after the bodies'. A class's mass (for the dose) is the sum over
    its voxels of the voxel's volume x its weight x the class's density, less the voxels whose
    centre lies inside a mesh body that displaces the volume (the voxels cut by that mesh's
    surface are counted whole or not at all).
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
    tracks: list = field(default_factory=list)

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
        # a region of no mass (a volume's class without voxels) receives nothing: 0 Gy
        dose = {nm: energy[nm] * joule / masses[k] if masses[k] > 0 else 0.0
                for k, nm in enumerate(names)}
        dose_error = {nm: energy_error[nm] * joule / masses[k] if masses[k] > 0 else 0.0
                      for k, nm in enumerate(names)}
    return Transport(histories=n, energy=energy, energy_error=energy_error, images=images,
                     image_errors=image_errors, balance={k: float(v) for k, v in balance.items()},
                     dose=dose, dose_error=dose_error, seed=seed,
                     balance_error=balance_error)
