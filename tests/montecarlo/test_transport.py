"""The photon transport (xray_viz.transport): physics tables and samplers against xraylib,
the geometry's watertight crossings, conservation, reproducibility, the primary image against
Beer-Lambert."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import trimesh
import xraylib
from scipy import stats

from xray_viz.montecarlo.sources import pixel_shares

import xray_viz
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.montecarlo import geometry as G
from xray_viz.montecarlo import physics as P
from xray_viz.montecarlo.rng import batch_states


# --- physics ------------------------------------------------------------------------------

@pytest.mark.parametrize("material, density", [("Water, Liquid", 1.0),
                                               ("Bone, Cortical (ICRP)", 1.85),
                                               ({"H2O": 0.9, "NaCl": 0.1}, 1.07),
                                               ("Tissue, Soft (ICRU-44)", 1.06)])
def test_total_mu_is_the_primary_engines_and_xraylibs(material, density):
    from xray_viz.physics.materials import linear_attenuation

    t = P.tables([("m", material, density)], e_max=150.0)
    e = np.array([5.5, 12.0, 33.3, 56.4, 80.0, 120.0, 149.0])
    ours = np.array([sum(P.mu_lookup(t.mu[0], t.ln_e0, t.d_ln_e, x)) * 10 for x in e])
    theirs = linear_attenuation(material, e, density=density)
    np.testing.assert_allclose(ours, theirs, rtol=2e-5)
    # each process against xraylib's own compound cross sections
    if material == "Water, Liquid":
        for x in e:
            photo, incoh, coh = P.mu_lookup(t.mu[0], t.ln_e0, t.d_ln_e, x)
            assert photo * 10 == pytest.approx(xraylib.CS_Photo_CP(material, x), rel=2e-5)
            assert incoh * 10 == pytest.approx(xraylib.CS_Compt_CP(material, x), rel=2e-5)
            assert coh * 10 == pytest.approx(xraylib.CS_Rayl_CP(material, x), rel=2e-5)


def test_total_mu_against_nist_xcom():
    # NIST XCOM, water, total with coherent (cm2/g): 20 keV 0.8096, 60 keV 0.2059, 100 keV 0.1707
    t = P.tables([("w", "Water, Liquid", 1.0)], e_max=120.0)
    for e, nist in ((20.0, 0.8096), (60.0, 0.2059), (100.0, 0.1707)):
        assert sum(P.mu_lookup(t.mu[0], t.ln_e0, t.d_ln_e, e)) * 10 == pytest.approx(nist,
                                                                                     rel=0.01)


@numba.njit
def _draw(n, energy, sf, cum, dx, state, coherent):
    out = np.empty(n)
    for i in range(n):
        if coherent:
            out[i] = P.sample_coherent(energy, cum, dx, state)
        else:
            out[i] = P.sample_incoherent(energy, sf, dx, state)[0]
    return out


def _dcs(material, energy, cost, coherent):
    """xraylib's differential cross section per unit cos(theta) of a compound (cm2/g)."""
    comp = P.composition(material)
    theta = np.arccos(np.clip(cost, -1, 1))
    f = xraylib.DCS_Rayl if coherent else xraylib.DCS_Compt
    return np.array([2 * np.pi * sum(w * f(z, energy, th) for z, w in comp.items())
                     for th in theta])


@pytest.mark.parametrize("energy", [16.8, 56.4, 120.0])
@pytest.mark.parametrize("coherent", [False, True])
def test_scattering_angles_follow_xraylibs_differential_cross_sections(energy, coherent):
    material = "Water, Liquid"
    t = P.tables([("w", material, 1.0)], e_max=150.0)
    n = 200_000
    cost = _draw(n, energy, t.sf[0], t.ff2_cum[0], t.dx, batch_states(3, 1)[0], coherent)
    edges = np.linspace(-1, 1, 41)
    if coherent:                          # forward-peaked: finer bins where the counts are
        edges = np.unique(np.concatenate([np.linspace(-1, 0.8, 19), np.linspace(0.8, 1, 22)]))
    counts, _ = np.histogram(cost, edges)
    # expected: xraylib's DCS integrated over each bin (Gauss-Legendre, 8 points)
    x, w = np.polynomial.legendre.leggauss(8)
    mids, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
    pts = (mids[:, None] + half[:, None] * x[None, :]).ravel()
    vals = _dcs(material, energy, pts, coherent).reshape(len(mids), 8)
    per_bin = (vals * w[None, :]).sum(axis=1) * half
    expected = n * per_bin / per_bin.sum()
    keep = expected > 20
    chi2 = float((((counts - expected) ** 2) / expected)[keep].sum())
    p = stats.chi2.sf(chi2, keep.sum() - 1)
    assert p > 1e-3, (chi2, keep.sum())
    # and the integral is xraylib's total cross section of the process
    total = per_bin.sum()
    cs = (xraylib.CS_Rayl_CP if coherent else xraylib.CS_Compt_CP)(material, energy)
    assert total == pytest.approx(cs, rel=0.02)


# --- geometry -----------------------------------------------------------------------------

def _crossings(bvh, o, d):
    """Every crossing of the ray (t, body, entering) as the transport walks it."""
    stack = np.zeros(64, np.int64)
    tb = np.zeros(16, np.int64)
    te = np.zeros(16, np.bool_)
    out, t = [], 0.0
    while True:
        t, n = G.next_crossing(o, d, t, np.inf, bvh, stack, tb, te)
        if n == 0:
            return out
        out.extend((t, int(tb[k]), bool(te[k])) for k in range(n))


def test_photons_aimed_at_vertices_and_edges_never_leak():
    from xray_viz.tracing.intersect import watertight_intersect

    mesh = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    cube = trimesh.creation.box(extents=[8, 8, 8])        # axis-aligned: ties on every axis
    bvh_s = G.build_bvh(mesh.triangles, np.zeros(len(mesh.faces), int))
    bvh_c = G.build_bvh(cube.triangles, np.zeros(12, int))
    rng = np.random.default_rng(0)
    grazing = rays = 0
    for m, bvh in ((mesh, bvh_s), (cube, bvh_c)):
        targets = list(m.vertices) + [m.vertices[a] * 0.5 + m.vertices[b] * 0.5
                                      for a, b in m.edges_unique]
        for target in targets:
            for _ in range(2):
                o = rng.normal(size=3)
                o = 40 * o / np.linalg.norm(o)
                d = (target - o) / np.linalg.norm(target - o)
                hits = _crossings(bvh, o, d)
                # after the crossings at each t: inside once or outside, never twice or
                # "outside the outside"; out at the end (a silhouette: in and out at one t)
                ts = sorted({t for t, _, _ in hits})
                inside = [sum(1 if e else -1 for t, _, e in hits if t <= u) for u in ts]
                assert set(inside) <= {0, 1} and (not ts or inside[-1] == 0)
                assert len(ts) in (0, 1, 2)
                grazing += len(ts) < 2
                rays += 1
                tri = m.triangles
                hit, tt, _, ent = watertight_intersect(
                    np.tile(o, (len(tri), 1)), np.tile(d, (len(tri), 1)),
                    tri[:, 0], tri[:, 1], tri[:, 2])
                assert sorted(tt[hit].tolist()) == [t for t, _, _ in hits]  # the same bits
    # rays from a face's inside through the cube's vertices: the axis-aligned ties
    for v in cube.vertices:
        o = np.array([0.1, 0.2, -0.3])
        d = (v - o) / np.linalg.norm(v - o)
        hits = _crossings(bvh_c, o, d)
        assert [e for _, _, e in hits] == [False]
    assert grazing < 0.1 * rays              # most rays through a vertex or edge cross


def test_exact_sign_is_exact_where_rounding_is_not():
    a, b, c = 1.0 + 2.0 ** -52, 1.0 - 2.0 ** -53, 1.0   # a b - c: 2^-53 - 2^-105, rounds to 0
    from fractions import Fraction
    for (p, q, r, s) in ((a, b, c, 1.0), (3.0, 1 / 3, 1.0, 1.0), (0.1, 0.3, 0.3, 0.1),
                         (1e-300, 1e-10, 0.0, 1.0)):
        exact = Fraction(p) * Fraction(q) - Fraction(r) * Fraction(s)
        assert G.exact_sign(p, q, r, s) == (exact > 0) - (exact < 0)


# --- transport ----------------------------------------------------------------------------

def _scene(energy=60.0, world=None, shape=(16, 16), pitch=(8.0, 8.0), **detector):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=30)
    slab = trimesh.creation.box(extents=[120, 120, 80])
    return Scene(source=Source(position=[0, 0, 600], energy=energy),
                 detector=Detector(center=[0, 0, -400], shape=shape, pitch=pitch, **detector),
                 bodies=(Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)"),
                         Body(name="water", mesh=slab, material="Water, Liquid")),
                 world=world)


def test_energy_balance_and_same_seed_same_bits():
    scene = _scene(world={"material": "Air, Dry (near sea level)"})
    a = xray_viz.transport(scene, 40_000, seed=5)
    b = a.balance
    total = b["deposited"] + b["world"] + b["escaped"] + b["detector"]
    assert total == pytest.approx(b["emitted"], rel=1e-12)
    assert b["emitted"] == pytest.approx(60_000.0, rel=1e-12)
    assert b["deposited"] == pytest.approx(sum(a.energy.values()), rel=1e-12)
    assert b["world"] > 0 and all(v > 0 for v in a.energy.values())
    from xray_viz import _threads
    again = xray_viz.transport(scene, 40_000, seed=5)
    assert again.energy == a.energy
    assert all((again.images[k] == a.images[k]).all() for k in a.images)
    other = xray_viz.transport(scene, 40_000, seed=6)
    assert other.energy != a.energy
    # one thread or three: the same bits (batches added in batch order whatever ran them)
    from xray_viz.transport import prepare
    from xray_viz.montecarlo.tallies import run_group
    p = prepare(scene, 40_000, seed=5)
    one, three = run_group(p, 0, threads=1), run_group(p, 0, threads=3)
    assert (one.dep == three.dep).all() and (one.img == three.img).all()
    assert _threads.count() >= 1


def test_primary_image_is_beer_lambert():
    scene = _scene(energy=50.0, shape=(8, 8), pitch=(15.0, 15.0), supersample=4)
    n = 100_000
    result = xray_viz.transport(scene, n, seed=2)
    li = xray_viz.render(scene).line_integral          # the primary engines, same energy
    share = pixel_shares(scene.acquisition)      # each pixel's share of the field
    expected = 50_000.0 * share * np.exp(-li)
    got, err = result.images["primary"], result.image_errors["primary"]
    z = (got - expected) / err
    assert abs(z.mean()) * np.sqrt(z.size) < 4 and np.abs(z).max() < 5
    assert got.sum() == pytest.approx(expected.sum(), rel=4 * np.sqrt((err ** 2).sum()) / got.sum())
    # scatter is there and smaller than the primary here
    assert 0 < result.images["incoherent"].sum() < got.sum()


@pytest.mark.parametrize("bad, match", [(0, "histories must be > 0"),
                                        (-5, "histories must be > 0"),
                                        (1.5, "whole number")])
def test_bad_histories(bad, match):
    with pytest.raises(xray_viz.SceneError, match=match):
        xray_viz.transport(_scene(), bad)


def test_body_without_material_and_unknown_world():
    scene = Scene(source=Source(position=[0, 0, 600]), detector=Detector(center=[0, 0, -400]),
                  bodies=(Body(name="ball", mesh=trimesh.creation.icosphere(), mu=0.2),))
    with pytest.raises(xray_viz.SceneError, match="'ball' gives only 'mu'"):
        xray_viz.transport(scene, 10)
    with pytest.raises(xray_viz.MaterialError, match=r"\[world\] unknown material"):
        _scene(world={"material": "Unobtainium"})


def test_world_round_trips_through_the_scene_file():
    from xray_viz.scene import scene_from_dict

    doc = xray_viz.load_scene("sphere").to_dict()
    doc["world"] = {"material": "Air, Dry (near sea level)"}
    scene = scene_from_dict(doc)
    assert scene.world["density"] == pytest.approx(0.001205, rel=1e-3)
    again = scene_from_dict(scene.to_dict())
    assert again.world == scene.world
    assert xray_viz.load_scene("sphere").world is None               # vacuum by default
    doc["world"] = {"material": "H2O"}
    with pytest.raises(xray_viz.MaterialError, match=r"\[world\] material 'H2O' .*density"):
        scene_from_dict(doc)


@pytest.mark.parametrize("detector", [
    {"center": [0, 0, -400], "shape": (10, 6), "pitch": (9.0, 14.0), "offset": (25.0, -10.0)},
    {"center": [30, 0, -400], "shape": (8, 8), "pitch": (10.0, 10.0),
     "u": [np.cos(0.4), 0.0, np.sin(0.4)], "v": [0.0, 1.0, 0.0]},
])
def test_every_photon_reaches_an_offset_or_tilted_detectors_field_in_vacuum(detector):
    scene = Scene(source=Source(position=[0, 0, 600], energy=40.0),
                  detector=Detector(**detector), bodies=())
    result = xray_viz.transport(scene, 20_000, seed=1)
    assert result.balance["detector"] == pytest.approx(40_000.0, rel=1e-12)   # all of them
    image = result.images["primary"]
    assert image.sum() == pytest.approx(40_000.0, rel=1e-12)
    assert (image > 0).all()                           # the field is the whole detector
    # uniform per solid angle: each pixel's share is its solid angle's
    from xray_viz.montecarlo.sources import rectangle_solid_angle, solid_angle
    f = scene.acquisition.frame
    (w, h), (pu, pv) = f.shape, f.pitch
    share = np.array([[rectangle_solid_angle(
        f.source, f.middle + ((c + 0.5) - w / 2) * pu * f.ho + (h / 2 - (r + 0.5)) * pv * f.ve,
        f.ho, f.ve, pu / 2, pv / 2) for c in range(w)] for r in range(h)])
    assert share.sum() == pytest.approx(solid_angle(scene.acquisition), rel=1e-9)
    expected = 40_000.0 * share / share.sum()
    z = (image - expected) / result.image_errors["primary"]
    assert np.abs(z).max() < 5 and abs(z.mean()) * np.sqrt(z.size) < 4


def test_parallel_beam_primary_is_beer_lambert():
    slab = trimesh.creation.box(extents=[200, 200, 50])          # every ray crosses 50 mm
    scene = Scene(source=Source(position=[0, 0, 600], kind="parallel", energy=60.0),
                  detector=Detector(center=[0, 0, -400], shape=(4, 4), pitch=(20.0, 20.0)),
                  bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),))
    result = xray_viz.transport(scene, 40_000, seed=8)
    # one body: the error of all the bodies' energy is that body's
    assert result.balance_error["deposited"] == pytest.approx(result.energy_error["water"],
                                                              rel=1e-9)
    from xray_viz.physics.materials import linear_attenuation
    transmitted = float(np.exp(-linear_attenuation("Water, Liquid", 60.0)[0] * 5.0))
    got = result.images["primary"].sum() / 60_000.0
    err = np.sqrt((result.image_errors["primary"] ** 2).sum()) / 60_000.0
    assert abs(got - transmitted) < 4 * err
    b = result.balance
    assert b["deposited"] + b["escaped"] + b["detector"] == pytest.approx(b["emitted"], rel=1e-12)


def test_an_interrupted_transport_keeps_its_finished_groups():
    scene = _scene()
    calls = []

    def stop_after_first(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    # batches of 100: 5000 histories are 50 batches in 4 groups of 16
    full = xray_viz.transport(scene, 5000, seed=4, batch=100)
    part = xray_viz.transport(scene, 5000, seed=4, batch=100, progress=stop_after_first,
                              interruptible=True)
    assert part.extra["interrupted"] and part.histories == 3200 and calls == [1600, 3200]
    first_two = xray_viz.transport(scene, 3200, seed=4, batch=100)
    assert part.energy == first_two.energy                   # the finished groups, exactly
    assert full.histories == 5000 and not full.extra["interrupted"]
    calls.clear()
    with pytest.raises(KeyboardInterrupt):                    # not asked to keep them
        xray_viz.transport(scene, 5000, seed=4, batch=100, progress=stop_after_first)


def test_region_masses_of_nested_and_partly_overlapping_bodies():
    from xray_viz.transport import _region_masses, prepare

    def box(size, at):
        m = trimesh.creation.box(extents=[size] * 3)
        m.apply_translation(at)
        return m

    bodies = (Body(name="a", mesh=box(40, [0, 0, 0]), material="Water, Liquid"),
              Body(name="b", mesh=box(40, [20, 0, 0]), material="Water, Liquid"),   # wins a/b
              Body(name="c", mesh=box(10, [-10, 0, 0]), material="Water, Liquid"))  # inside a
    scene = Scene(source=Source(position=[0, 0, 600]), detector=Detector(center=[0, 0, -400]),
                  bodies=bodies)
    p = prepare(scene, 1)
    kg = _region_masses(scene, [1.0, 1.0, 1.0], p["bvh"], p["rank_order"])
    mm3 = kg / 1e-6
    assert mm3[2] == pytest.approx(1000.0)                       # c: exact
    assert mm3[1] == pytest.approx(64000.0, rel=0.01)            # b wins the overlap
    assert mm3[0] == pytest.approx(64000.0 - 32000.0 - 1000.0, rel=0.01)   # a: less both


def test_pixel_shares_add_up_to_the_field_and_flat_signal_is_the_vacuum_image():
    from xray_viz.transport import flat_signal

    scene = _scene(energy=50.0, shape=(6, 4), pitch=(15.0, 15.0))
    share = pixel_shares(scene.acquisition)
    assert share.shape == (4, 6) and share.sum() == pytest.approx(1.0, rel=1e-12)
    assert np.allclose(share, share[::-1, :]) and np.allclose(share, share[:, ::-1])
    # in vacuum the transport's primary image is the flat signal, within its errors
    empty = scene.replace(bodies=())
    result = xray_viz.transport(empty, 50_000, seed=4)
    got, err = result.images["primary"], result.image_errors["primary"]
    z = (got - flat_signal(empty)) / err
    assert np.abs(z).max() < 5 and abs(z.mean()) * np.sqrt(z.size) < 4


def test_a_face_in_the_detector_plane_loses_no_photon():
    """A slab whose exit face lies in the detector plane: its crossing and the plane's are at
    the same distance; the photon is still detected (primary = Beer-Lambert, and the scatter as
    with a hair of air gap, within the errors)."""
    def scene(gap):
        slab = trimesh.creation.box(extents=[300, 300, 100])
        slab.apply_translation([0, 0, -400 + 50 + gap])
        return Scene(source=Source(position=[0, 0, 600], energy=60.0),
                     detector=Detector(center=[0, 0, -400], shape=(8, 8), pitch=(16.0, 16.0)),
                     bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),))

    touching = scene(0.0)
    result = xray_viz.transport(touching, 60_000, seed=6)
    li = xray_viz.render(touching).line_integral
    expected = 60_000.0 * pixel_shares(touching.acquisition) * np.exp(-li)
    got, err = result.images["primary"], result.image_errors["primary"]
    z = (got - expected) / err
    assert np.abs(z).max() < 5 and abs(z.mean()) * np.sqrt(z.size) < 4
    apart = xray_viz.transport(scene(0.5), 60_000, seed=7)
    scattered = [sum(r.images[k].sum() for k in ("incoherent", "coherent", "multiple"))
                 for r in (result, apart)]
    errs = [np.sqrt(sum((r.image_errors[k] ** 2).sum()
                        for k in ("incoherent", "coherent", "multiple"))) for r in (result, apart)]
    assert abs(scattered[0] - scattered[1]) < 4 * np.hypot(*errs)
