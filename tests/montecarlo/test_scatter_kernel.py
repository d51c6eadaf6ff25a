"""The scatter kernel model (xray_viz.scatter_kernel): its calibration file, the shape of its
scatter, its ranges, and its agreement with a fresh transport on slabs and small bodies it was
not fitted on."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.errors import SceneError, ScatterModelWarning
from xray_viz.scatter_kernel import (KernelModel, KernelParameters, PARAMETER_NAMES,
                                     TOLERANCE, load_parameters)
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.transport import flat_signal

AL = {"filters": {"Al": 2.5}}


def slab(thickness=150.0, field=150.0, gap=50.0, pixels=32, source=None, insert=None):
    """A water slab wider than the field, its exit side ``gap`` mm above a square detector
    ``field`` mm wide; source 1500 mm above the detector (80 kVp, 2.5 mm Al by default)."""
    side = 1.3 * field + 20.0
    box = trimesh.creation.box(extents=[side, side, thickness])
    box.apply_translation([0.0, 0.0, gap + thickness / 2])
    bodies = [Body(name="slab", mesh=box, material="Water, Liquid")]
    if insert is not None:
        inner = trimesh.creation.box(extents=[side - 4.0, side - 4.0, insert[1]])
        inner.apply_translation([0.0, 0.0, gap + thickness / 2])
        bodies.append(Body(name="insert", mesh=inner, material=insert[0]))
    keys = source if source is not None else {"spectrum": {"kvp": 80.0, **AL}}
    return Scene(source=Source(position=[0.0, 0.0, 1500.0], **keys),
                 detector=Detector(center=[0.0, 0.0, 0.0], shape=(pixels, pixels),
                                   pitch=(field / pixels, field / pixels)),
                 bodies=tuple(bodies))


#: The calibration before the small bodies were in it (water slabs and six blocks narrower
#: than the field; the edge term's reach fixed at tau c_edge + 1 mm)
PREVIOUS = {
    "a0": 0.404088,
    "a1": 1.021972,
    "a2": 0.327845,
    "a3": -0.278885,
    "a4": 0.019965,
    "fraction": 0.951372,
    "s1": 1.00179,
    "s2": 0.491477,
    "n1": 100.0,
    "n2": 1.669338,
    "b_edge": 0.370871,
    "c_edge": 0.154446,
    "l_edge": 1.0,
    # (the grid's parameters came later; they act behind a grid only)
    "grid_depth": 77.0,
    "grid_hardening": 0.39}


def cylinder(diameter=100.0, field=160.0, gap=100.0, pixels=16, source=None):
    """A water cylinder narrower than the field (along the detector's v axis, 0.75 of the
    field long), its lowest line ``gap`` mm above a square detector ``field`` mm wide; source
    1500 mm above the detector (60 keV by default)."""
    mesh = trimesh.creation.cylinder(radius=diameter / 2, height=0.75 * field, sections=96)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_translation([0.0, 0.0, gap + diameter / 2])
    keys = source if source is not None else {"energy": 60.0}
    return Scene(source=Source(position=[0.0, 0.0, 1500.0], **keys),
                 detector=Detector(center=[0.0, 0.0, 0.0], shape=(pixels, pixels),
                                   pitch=(field / pixels, field / pixels)),
                 bodies=(Body(name="cylinder", mesh=mesh, material="Water, Liquid"),))


def model_scatter(scene, *, materials=False):
    """(scatter, ln T) of the model for ``scene`` (with ``materials``, given each pixel's path
    lengths per body, as ``render(scatter="kernel")`` does)."""
    image = xray_viz.render(scene, path_lengths=materials)
    lengths = image.path_length if materials else None
    log_t = -image.line_integral
    return KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies,
                                         path_lengths=lengths), log_t


def centre(a, k=4):
    h, w = a.shape
    return float(a[h // 2 - k:h // 2 + k, w // 2 - k:w // 2 + k].mean())


# --- the calibration file ---------------------------------------------------------------------

def test_calibration_file_round_trips_and_records_its_fit(tmp_path):
    p = load_parameters()
    assert set(p.values) == set(PARAMETER_NAMES)
    for key in ("date", "commit", "histories", "cases"):
        assert key in p.meta
    assert p.meta["histories"] > 0 and len(p.meta["cases"]) >= 10
    path = tmp_path / "k.json"
    path.write_text(json.dumps(p.to_dict()))
    again = load_parameters(path)
    assert again.values == p.values and again.ranges == p.ranges and again.meta == p.meta


@pytest.mark.parametrize("change, match", [
    (lambda d: d["parameters"].pop("s1"), "parameters.s1 must be a finite number"),
    (lambda d: d["parameters"].update(a0="x"), "parameters.a0"),
    (lambda d: d["parameters"].update(a2=float("nan")), "parameters.a2"),
    (lambda d: d["ranges"].update(gap_mm=[300, 0]), "ranges.gap_mm"),
    (lambda d: d["ranges"].pop("field_mm"), "ranges.field_mm"),
    (lambda d: d["parameters"].update(fraction=1.5), "fraction"),
])
def test_a_malformed_calibration_is_refused_in_one_line(tmp_path, change, match):
    doc = load_parameters().to_dict()
    change(doc)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(SceneError, match=match) as info:
        load_parameters(path)
    assert "\n" not in str(info.value) and str(path) in str(info.value)


def test_unreadable_or_missing_calibration(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text("{not json")
    with pytest.raises(SceneError, match="not readable JSON") as info:
        load_parameters(path)
    assert "\n" not in str(info.value)
    with pytest.raises(SceneError, match="not found"):
        load_parameters(tmp_path / "none.json")


# --- the shape of the scatter -----------------------------------------------------------------

def test_nothing_in_the_beam_gives_no_scatter():
    scene = slab()
    empty = scene.replace(bodies=())
    model = KernelModel.of(empty)
    s = model.scatter(np.zeros((32, 32)), empty.acquisition, empty.bodies)
    assert s.shape == (32, 32) and not s.any()


def test_scatter_is_non_negative_finite_and_smooth():
    scene = xray_viz.load_scene("step_wedge")        # sharp steps in the primary
    s, log_t = model_scatter(scene)
    assert s.shape == log_t.shape and np.isfinite(s).all() and (s >= 0).all()
    assert s.max() > 0
    # the primary jumps at the steps; the scatter changes by < 1 % of its peak per pixel
    t = np.exp(log_t)
    assert np.abs(np.diff(t, axis=1)).max() > 0.1 * t.max()
    for axis in (0, 1):
        assert np.abs(np.diff(s, axis=axis)).max() < 0.01 * s.max()


def test_thicker_slab_or_larger_field_gives_a_larger_spr():
    def spr(**kw):
        s, log_t = model_scatter(slab(**kw))
        return centre(s) / centre(np.exp(log_t))

    thick = [spr(thickness=t) for t in (60.0, 120.0, 240.0)]
    wide = [spr(field=f) for f in (60.0, 150.0, 350.0)]
    assert thick[0] < thick[1] < thick[2]
    assert wide[0] < wide[1] < wide[2]
    # the air gap spreads the scatter: a small field's centre gets less of it
    assert spr(field=60.0, gap=250.0) < spr(field=60.0, gap=0.0)


def test_water_thickness_inverts_the_beams_own_water_transmission():
    scene = slab()
    model = KernelModel.of(scene)
    for t in (10.0, 100.0, 280.0):
        water = slab(thickness=t, pixels=4)
        log_t = -xray_viz.render(water).line_integral
        assert model.water_thickness(log_t).mean() == pytest.approx(t, rel=2e-3)


@pytest.mark.parametrize("kw, source, match", [
    ({"gap": 700.0}, None, "air gap 700 mm"),
    ({"field": 600.0}, None, "field side at the detector 600 mm"),
    ({"thickness": 420.0}, None, "water-equivalent thickness 42"),
    ({}, {"energy": 140.0}, "mean energy .* 140.0 keV"),
])
def test_outside_the_fitted_range_it_warns(kw, source, match):
    scene = slab(pixels=8, source=source, **kw)
    with pytest.warns(ScatterModelWarning, match=match):
        model_scatter(scene)


def test_inside_the_range_it_does_not_warn():
    scene = slab(pixels=8)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model_scatter(scene)


def test_parameters_given_explicitly_are_used():
    p = load_parameters()
    double = KernelParameters({**p.values, "a0": p.values["a0"] + np.log(2.0)}, p.ranges,
                              p.meta)
    scene = slab()
    log_t = -xray_viz.render(scene).line_integral
    one = KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies)
    two = KernelModel.of(scene, parameters=double).scatter(log_t, scene.acquisition,
                                                           scene.bodies)
    np.testing.assert_allclose(two, 2 * one, rtol=1e-12)


# --- against a fresh transport ----------------------------------------------------------------

def _against_transport(scene, histories, seed, block=8, materials=True):
    """Blocks of ``block`` pixels: (model / transport - 1, the transport's relative error)
    (and the same of the material-blind model with ``materials="both"``)."""
    r = xray_viz.transport(scene, histories, seed=seed)
    keys = ("incoherent", "coherent", "multiple")
    flat = flat_signal(scene)
    mc = sum(r.images[k] for k in keys) / flat
    err = np.sqrt(sum(r.image_errors[k] ** 2 for k in keys)) / flat
    s, _ = model_scatter(scene, materials=bool(materials))
    h, w = mc.shape

    def blocks(a, sq=False):
        x = a.reshape(h // block, block, w // block, block)
        return (np.sqrt((x ** 2).sum(axis=(1, 3))) if sq else x.sum(axis=(1, 3))) / block ** 2

    m, e = blocks(mc), blocks(err, sq=True)
    if materials == "both":
        blind, _ = model_scatter(scene)
        return blocks(s) / m - 1, e / m, blocks(blind) / m - 1
    return blocks(s) / m - 1, e / m


def test_path_lengths_of_water_give_the_water_model():
    # water's scatter-equivalent thickness is its path length, the transmission's inversion
    # gives the same thickness: the two ways agree to the look-up table's step
    scene = slab(thickness=140.0, field=200.0, gap=30.0, pixels=16)
    with_lengths, _ = model_scatter(scene, materials=True)
    without, _ = model_scatter(scene)
    np.testing.assert_allclose(with_lengths, without, rtol=2e-3)


def test_a_bone_body_scatters_less_than_water_of_the_same_attenuation():
    # 20 mm of cortical bone attenuates like about 55 mm of water at 80 kVp but scatters like
    # about 37 mm: with the path lengths the model gives it less scatter than without them
    scene = slab(thickness=150.0, field=150.0, gap=50.0, pixels=16,
                 insert=("Bone, Cortical (ICRP)", 20.0))
    model = KernelModel.of(scene)
    ratio = model.scattering_coefficients(scene.bodies)
    assert ratio[0] == pytest.approx(1.0) and 1.7 < ratio[1] < 2.0
    with_lengths, _ = model_scatter(scene, materials=True)
    without, _ = model_scatter(scene)
    assert 0.75 < centre(with_lengths) / centre(without) < 0.92


def test_path_lengths_of_the_wrong_shape_are_refused():
    scene = slab(pixels=8)
    log_t = -xray_viz.render(scene).line_integral
    with pytest.raises(SceneError, match=r"path_lengths of shape \(8, 8, 2\)"):
        KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies,
                                      path_lengths=np.zeros((8, 8, 2)))
    with pytest.raises(SceneError, match=r"scattering of shape \(4, 8\)"):
        KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies,
                                      scattering=np.zeros((4, 8)))


def test_the_summed_thickness_gives_what_the_path_lengths_give():
    scene = slab(thickness=150.0, field=150.0, gap=50.0, pixels=16,
                 insert=("Bone, Cortical (ICRP)", 20.0))
    image = xray_viz.render(scene, path_lengths=True)
    model = KernelModel.of(scene)
    weights = model.path_weights(scene.acquisition, scene.bodies)
    args = (-image.line_integral, scene.acquisition, scene.bodies)
    np.testing.assert_allclose(model.scatter(*args, scattering=image.path_length @ weights),
                               model.scatter(*args, path_lengths=image.path_length),
                               rtol=1e-12)


def test_model_within_its_tolerance_of_a_fresh_transport_on_a_held_out_slab():
    # 130 mm, a 120 mm field, a 40 mm gap, 80 kVp: none of the calibration's values
    scene = slab(thickness=130.0, field=120.0, gap=40.0, pixels=16)
    dev, rel = _against_transport(scene, 400_000, seed=39)
    assert rel.max() < 0.05                          # the transport's own precision
    # each block within the stated tolerance plus three of the transport's standard errors
    assert (np.abs(dev) < TOLERANCE + 3 * rel).all(), (dev, rel)


def test_model_within_its_tolerance_of_a_fresh_transport_on_a_bone_layer():
    # 15 mm of cortical bone in 130 mm of water (not in the fit, which saw water alone): the
    # material-blind model (water-equivalent thickness of the transmission) is high here,
    # the path lengths per body bring it within the tolerance (-3 to -10 %, the transport's
    # error 3 % per block)
    scene = slab(thickness=130.0, field=120.0, gap=40.0, pixels=16,
                 insert=("Bone, Cortical (ICRP)", 15.0))
    dev, rel, blind = _against_transport(scene, 400_000, seed=39, materials="both")
    assert rel.max() < 0.05
    assert (np.abs(dev) < TOLERANCE + 3 * rel).all(), (dev, rel)
    # the material-blind model is 10-18 % high here; the two differ by about 19 % (the
    # transport's noise cancels in the difference)
    assert np.median(blind - dev) > 0.12, (blind, dev)


def test_model_within_its_tolerance_of_a_fresh_transport_on_a_small_body():
    # a water cylinder 60 mm across in a 120 mm field, 60 mm above the detector, 60 keV:
    # narrower than the field, a field and gap the fit's cylinders (25, 40, 60, 80, 120,
    # 150 mm across) did not have. Measured +5 to +8 % per block (the transport's error
    # 2 %); the calibration before the small bodies were in it +14 to +18 %. Pixels of
    # about 4 mm (the calibration's: 3-9 mm); at 12 mm the model is some 10 points higher
    # on such bodies, with the earlier calibration too (BENCHMARKS.md)
    scene = cylinder(diameter=60.0, field=120.0, gap=60.0, pixels=32)
    dev, rel = _against_transport(scene, 400_000, seed=39, block=16)
    assert rel.max() < 0.03
    # each of the four blocks within the stated tolerance plus three of the transport's
    # standard errors
    assert (np.abs(dev) < TOLERANCE + 3 * rel).all(), (dev, rel)
    # the earlier calibration (no small bodies in the fit, the edge term's reach
    # c_edge tau + 1 mm) gives about 9 % more here: the transport's noise cancels in the ratio
    old = KernelParameters(PREVIOUS, load_parameters().ranges, {})
    image = xray_viz.render(scene, path_lengths=True)
    before = KernelModel.of(scene, parameters=old).scatter(
        -image.line_integral, scene.acquisition, scene.bodies, path_lengths=image.path_length)
    now, _ = model_scatter(scene, materials=True)
    assert 1.05 < before.sum() / now.sum() < 1.15


@pytest.mark.slow
@pytest.mark.parametrize("make", [
    lambda: cylinder(diameter=70.0, field=200.0, gap=250.0, pixels=32,
                     source={"spectrum": {"kvp": 80.0, **AL}}),
    # a large cylinder near the detector: within 5 % over the body since the air gaps are
    # taken from its exit side, but 13-18 % low beside it (BENCHMARKS.md, fourth pass)
    pytest.param(lambda: cylinder(diameter=130.0, field=240.0, gap=40.0, pixels=32,
                                  source={"spectrum": {"kvp": 100.0, **AL}}),
                 marks=pytest.mark.xfail(strict=True, reason="low beside a large body near "
                                         "the detector")),
])
def test_model_within_its_tolerance_of_the_transport_on_small_bodies(make):
    dev, rel = _against_transport(make(), 6_000_000, seed=43)
    ok = rel < 0.02
    assert ok.sum() >= 4
    assert (np.abs(dev[ok]) < TOLERANCE + 3 * rel[ok]).all(), (dev, rel)


@pytest.mark.slow
@pytest.mark.parametrize("make", [
    lambda: slab(thickness=180.0, field=250.0, gap=80.0, pixels=32,
                 source={"spectrum": {"kvp": 100.0, **AL}},
                 insert=("Bone, Cortical (ICRP)", 25.0)),
    lambda: slab(thickness=100.0, field=200.0, gap=60.0, pixels=32, source={"energy": 50.0},
                 insert=("Bone, Cortical (ICRP)", 10.0)),
])
def test_model_within_its_tolerance_of_the_transport_on_bone_layers(make):
    dev, rel = _against_transport(make(), 6_000_000, seed=42)
    ok = rel < 0.02
    assert ok.sum() >= 4
    assert (np.abs(dev[ok]) < TOLERANCE + 3 * rel[ok]).all(), (dev, rel)


@pytest.mark.slow
@pytest.mark.parametrize("make", [
    lambda: slab(thickness=220.0, field=300.0, gap=120.0, pixels=32,
                 source={"spectrum": {"kvp": 110.0, **AL}}),
    lambda: slab(thickness=90.0, field=260.0, gap=180.0, pixels=32,
                 source={"energy": 50.0}),
])
def test_model_within_its_tolerance_of_the_transport_on_held_out_slabs(make):
    dev, rel = _against_transport(make(), 6_000_000, seed=40)
    ok = rel < 0.02
    assert ok.sum() >= 4
    assert (np.abs(dev[ok]) < TOLERANCE + 3 * rel[ok]).all(), (dev, rel)


# --- the anti-scatter grid --------------------------------------------------------------------

def _clear_grid():
    """A grid whose strips and interspace attenuate nothing: it passes every photon at every
    angle (the identity of the grid's weighting)."""
    from xray_viz.physics.grid import Grid

    class Clear(Grid):
        def attenuation(self, energies_kev):
            e = np.asarray(energies_kev, dtype=np.float64)
            return np.zeros(e.shape), np.zeros(e.shape)

    return Clear()


@pytest.mark.parametrize("gap", [2.0, 80.0])         # below a cell (no spread), and a gap
def test_a_grid_lowers_the_spr_and_a_clear_one_changes_nothing(gap):
    import dataclasses

    from xray_viz.physics.grid import Grid

    scene = slab(gap=gap)
    log_t = -xray_viz.render(scene).line_integral
    bare = KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies)
    clear_scene = scene.replace(detector=dataclasses.replace(scene.detector,
                                                             grid=_clear_grid()))
    clear = KernelModel.of(clear_scene)
    assert clear.grid_primary == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(clear.scatter(log_t, clear_scene.acquisition,
                                             clear_scene.bodies), bare, rtol=1e-9, atol=0)
    gridded = scene.replace(detector=dataclasses.replace(scene.detector, grid=Grid()))
    log_g = -xray_viz.render(gridded).line_integral
    model = KernelModel.of(gridded)
    assert 0.5 < model.grid_primary < 0.9
    with_grid = model.scatter(log_g, gridded.acquisition, gridded.bodies)
    spr_bare = centre(bare) / centre(np.exp(log_t))
    spr_grid = centre(with_grid) / centre(np.exp(log_g))
    assert spr_grid < 0.5 * spr_bare


@pytest.mark.parametrize("grid", [{}, {"ratio": 8.0, "frequency": 40.0,
                                       "focus_distance": 1800.0}])
def test_behind_a_grid_within_its_tolerance_of_a_fresh_transport(grid):
    # a 150 mm water slab, a 200 mm field, 60 mm above the detector, 80 kVp: behind the
    # default grid (its angles fitted on 7 other cases behind it) and behind a grid the fit
    # did not see (8:1, 40 lines/cm, focused at 1800 mm: 1500 mm from the source, cut off
    # toward the edges), each block of the scatter (over each pixel's flat field, the grid's
    # cut-off in it) within the tolerance plus three of the transport's standard errors
    import dataclasses

    from xray_viz.physics.grid import Grid

    scene = slab(thickness=150.0, field=200.0, gap=60.0, pixels=16)
    gridded = scene.replace(detector=dataclasses.replace(scene.detector, grid=Grid(**grid)))
    dev, rel = _against_transport(gridded, 3_000_000, seed=41, block=4)
    assert rel.max() < 0.03
    assert (np.abs(dev) < TOLERANCE + 3 * rel).all(), (dev, rel)


# --- the materials' scattering ----------------------------------------------------------------

@pytest.mark.parametrize("material", ["Water, Liquid", "Bone, Cortical (ICRP)", "Al"])
def test_mass_scattering_plus_photoabsorption_is_the_attenuation(material):
    import xraylib

    from xray_viz.physics.materials import mass_attenuation, mass_scattering

    e = np.array([30.0, 60.0, 100.0])
    photo = np.array([xraylib.CS_Photo_CP(material, x) for x in e])
    np.testing.assert_allclose(mass_scattering(material, e) + photo,
                               mass_attenuation(material, e), rtol=1e-9)
    # the differential cross sections over the whole sphere give the total again
    whole = mass_scattering(material, e, cone=np.pi)
    np.testing.assert_allclose(whole, mass_scattering(material, e), rtol=0.01)
    # a narrow cone holds a larger share of the coherent (forward-peaked) scattering
    narrow = mass_scattering(material, 60.0, cone=np.radians(10.0))[0]
    assert 0 < narrow < 0.2 * whole[1]


def test_a_narrow_cone_weighs_aluminium_more_against_water():
    scene = xray_viz.load_scene("step_wedge")                 # Al, 490 mm above the detector
    model = KernelModel.of(scene)
    whole = model.scattering_coefficients(scene.bodies)[0]
    gap, _ = model.geometry(scene.acquisition, scene.bodies)
    cone = model.cone(scene.acquisition, gap)
    assert np.degrees(cone) < 10
    assert model.scattering_coefficients(scene.bodies, cone=cone)[0] > 1.5 * whole
    with pytest.raises(xray_viz.errors.MaterialError, match="cone"):
        from xray_viz.physics.materials import mass_scattering

        mass_scattering("Al", 60.0, cone=4.0)


def test_kernels_kept_on_the_model_match_the_exact_heights_and_are_reused(monkeypatch):
    """The kernels kept on the model (heights rounded to HEIGHT_STEP) give the scatter of the
    exact heights within 0.2 % of its maximum, and a second view of the same body computes no
    new kernel."""
    import xray_viz.scatter_kernel as sk

    scene = slab(thickness=120.0, field=200.0, gap=60.0, pixels=64)
    log_t = -xray_viz.render(scene).line_integral
    kept = KernelModel.of(scene)
    first = kept.scatter(log_t, scene.acquisition, scene.bodies)
    n = len(kept._spreads[1])
    again = kept.scatter(log_t, scene.acquisition, scene.bodies)
    assert len(kept._spreads[1]) == n > 0
    np.testing.assert_array_equal(again, first)
    monkeypatch.setattr(sk, "HEIGHT_STEP", 1e-9)
    exact = KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies)
    diff = np.abs(first - exact).max() / exact.max()
    assert 0.0 < diff < 2e-3


# --- the bodies' exit side, the edge term, the coherent share -------------------------------

def _with(**values):
    p = load_parameters()
    return KernelParameters({**p.values, **values}, p.ranges, p.meta)


def test_exit_heights_of_a_slab_are_its_exit_face_and_nan_outside_the_shadow():
    scene = slab(thickness=80.0, field=200.0, gap=37.0, pixels=32)
    h = KernelModel.exit_heights(scene.acquisition, scene.bodies, (8, 8), 4)
    np.testing.assert_allclose(h, 37.0, atol=1e-9)
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=30.0)
    mesh.apply_translation([0.0, 0.0, 100.0])
    ball = scene.replace(bodies=(Body(name="ball", mesh=mesh, material="Water, Liquid"),))
    h = KernelModel.exit_heights(ball.acquisition, ball.bodies, (16, 16), 2)
    assert np.isnan(h[0, 0]) and np.isnan(h[-1, -1])
    assert np.nanmin(h) == pytest.approx(70.0, abs=0.5)


def test_exit_heights_follow_the_exit_side_of_a_cylinder():
    # the exit points of the NumPy engine's rays through the cells' centres: within a
    # cell's rise of the surface (the cell's lowest surface point, not its centre's)
    from xray_viz.tracing.engines import Projector

    scene = cylinder(diameter=100.0, field=200.0, gap=30.0, pixels=16)
    h = KernelModel.exit_heights(scene.acquisition, scene.bodies, (16, 16), 1)
    _, hits = Projector(scene.bodies, "numpy").hits(scene.acquisition)
    last = np.r_[np.nonzero(np.diff(hits.ray))[0], len(hits.ray) - 1]
    exact = np.full(256, np.nan)
    exact[hits.ray[last]] = hits.point[last, 2]
    exact = exact.reshape(16, 16)
    both = np.isfinite(h) & np.isfinite(exact)
    assert both.sum() > 60
    assert np.all(h[both] <= exact[both] + 0.5)
    # away from the shadow's edge the surface rises less than 12 mm across a 12.5 mm cell
    inner = both & (np.abs(exact - 30.0) < 20.0)
    assert inner.sum() > 20 and np.all(exact[inner] - h[inner] < 12.0)
    # the exit side rises toward the shadow's edges: higher air gaps there
    row = h[8]
    assert row[np.isfinite(row)].max() > 60.0 and row[np.isfinite(row)].min() < 31.0


def test_the_edge_term_sends_a_share_from_under_a_narrow_body_out_by_its_sides():
    # the share it takes off near the shadow's edge leaves by the body's sides, evenly per
    # solid angle, mostly beyond this field: the scatter falls most under the body, less
    # beside it, and least at the field's edge, where the side emission lands
    scene = cylinder(diameter=80.0, field=200.0, gap=40.0, pixels=32,
                     source={"spectrum": {"kvp": 90.0, **AL}})
    log_t = -xray_viz.render(scene).line_integral
    args = (log_t, scene.acquisition, scene.bodies)
    off = KernelModel.of(scene, parameters=_with(b_edge=0.0)).scatter(*args)
    ratio = (KernelModel.of(scene).scatter(*args) / off)[16]
    b = load_parameters().values["b_edge"]
    inside = log_t[16] < 0
    assert inside[16] and not inside[0]
    assert np.all(ratio < 1.0) and ratio[inside].max() < 1.0 - 0.25 * b
    assert ratio[0] > ratio[5] > ratio[inside].max()           # rising away from the body


def test_a_spectrum_s_unattenuated_pixels_are_outside_the_shadow():
    # a tube spectrum's weights sum to 1 only to rounding: the unattenuated pixels invert to
    # ~1e-15 mm of water, which once counted as inside the shadow and turned the edge term
    # off for every polyenergetic body narrower than the field (TAU_MIN)
    from xray_viz.scatter_kernel import TAU_MIN

    scene = cylinder(diameter=60.0, field=200.0, gap=100.0, pixels=16,
                     source={"spectrum": {"kvp": 120.0, **AL}})
    model = KernelModel.of(scene)
    assert model.water_thickness(0.0) < TAU_MIN
    log_t = -xray_viz.render(scene).line_integral
    args = (log_t, scene.acquisition, scene.bodies)
    off = KernelModel.of(scene, parameters=_with(b_edge=0.0)).scatter(*args)
    assert np.abs(model.scatter(*args) - off).max() > 0.05 * off.max()


def test_the_coherent_share_is_left_out_of_the_edge_term():
    # an aluminium plate far above a small detector scatters mostly coherently into it:
    # the edge term takes off a smaller share of it than of water of the same scatter
    from xray_viz.scatter_kernel import KernelModel as KM

    def plate(material, density):
        box = trimesh.creation.box(extents=[40.0, 40.0, 8.0])
        box.apply_translation([0.0, 0.0, 404.0])
        return Scene(source=Source(position=[0.0, 0.0, 1500.0], energy=60.0),
                     detector=Detector(center=[0.0, 0.0, 0.0], shape=(16, 16),
                                       pitch=(6.0, 6.0)),
                     bodies=(Body(name="plate", mesh=box, material=material,
                                  density=density),))

    losses = []
    for material, density in (("Al", 2.699), ("Water, Liquid", None)):
        scene = plate(material, density)
        image = xray_viz.render(scene, path_lengths=True)
        args = (-image.line_integral, scene.acquisition, scene.bodies)
        on = KM.of(scene).scatter(*args, path_lengths=image.path_length)
        off = KM.of(scene, parameters=_with(b_edge=0.0)).scatter(
            *args, path_lengths=image.path_length)
        losses.append(1.0 - on.sum() / off.sum())
        w = KM.of(scene).path_weights(scene.acquisition, scene.bodies)
        assert w.shape == (1, 2) and 0 < w[0, 1] < w[0, 0]
    assert 0 <= losses[0] < 0.6 * losses[1]


def test_coherent_and_incoherent_scattering_add_to_the_whole():
    from xray_viz.errors import MaterialError
    from xray_viz.physics.materials import mass_scattering

    e = np.array([30.0, 60.0, 100.0])
    for material in ("Water, Liquid", "Bone, Cortical (ICRP)", "Al"):
        for cone in (None, np.radians(12.0)):
            parts = [mass_scattering(material, e, cone=cone, process=k)
                     for k in ("coherent", "incoherent")]
            np.testing.assert_allclose(parts[0] + parts[1],
                                       mass_scattering(material, e, cone=cone), rtol=1e-12)
    with pytest.raises(MaterialError, match="scattering process 'rayleigh'") as info:
        mass_scattering("Al", 60.0, process="rayleigh")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("insert", [None, ("Bone, Cortical (ICRP)", 20.0)])
def test_the_render_gives_the_model_of_the_path_lengths(insert):
    # one material (its coherent share a number) or two (the renderer sums the coherent
    # part per pixel): render(scatter="kernel") reads what the model gives from the path
    # lengths per body
    from xray_viz.physics.imaging import flat_field

    scene = slab(thickness=150.0, field=150.0, gap=50.0, pixels=16, insert=insert)
    image = xray_viz.render(scene, path_lengths=True)
    expected = KernelModel.of(scene).scatter(-image.line_integral, scene.acquisition,
                                             scene.bodies, path_lengths=image.path_length)
    rendered = xray_viz.render(scene, scatter="kernel").scatter / flat_field(scene)
    np.testing.assert_allclose(rendered, expected, rtol=1e-9, atol=1e-15)
