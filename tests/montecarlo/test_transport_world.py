"""The world medium (``[world]``) in the primary engines' images (issue 38): each ray's path
outside the bodies attenuated by the world's mu(E), against xraylib's mu analytically and
against the photon transport's primary image."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
import xraylib

from xray_viz.montecarlo.sources import pixel_shares

import xray_viz
from xray_viz.geometry import detector_rays
from xray_viz.scene import Body, Detector, Scene, Source

AIR = "Air, Dry (near sea level)"


def _air_mu_per_mm(energy, density=None):
    """xraylib's own total attenuation of dry air (NIST compound), 1/mm."""
    air = xraylib.GetCompoundDataNISTByName(AIR)
    rho = air["density"] if density is None else density
    return xraylib.CS_Total_CP(AIR, energy) * rho / 10.0


def _far_box():
    """A small body off the beam (the scene's bodies may not be empty)."""
    return Body(name="aside", mesh=trimesh.creation.box(extents=[5, 5, 5]).apply_translation(
        [900, 900, 900]), material="Water, Liquid")


def test_tg195_air_removes_about_4_percent_at_56_kev():
    # TG-195 case 2: source 1800 mm from the detector, in air
    scene = Scene(source=Source(position=[0, 0, 1800], energy=56.4),
                  detector=Detector(center=[0, 0, 0], shape=(6, 4), pitch=(40.0, 50.0)),
                  bodies=(_far_box(),), world={"material": AIR})
    image = xray_viz.render(scene)
    t_max = detector_rays(scene).t_max.reshape(4, 6)
    expected = np.exp(-_air_mu_per_mm(56.4) * t_max)
    assert image.intensity == pytest.approx(expected, rel=1e-12)
    centre_loss = 1 - np.exp(-_air_mu_per_mm(56.4) * 1800.0)
    assert 0.035 < centre_loss < 0.045                    # "~4 %": 1.8 m of air at 56 keV
    assert image.intensity.max() <= 1 - centre_loss + 1e-15
    vacuum = xray_viz.render(scene.replace(world=None))
    assert (vacuum.intensity == 1.0).all()


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_world_path_is_the_ray_minus_its_paths_in_the_bodies(kind):
    # nested bodies: each stretch counted once (the engines' precedence), a spectrum
    ball = trimesh.creation.icosphere(subdivisions=3, radius=30)
    slab = trimesh.creation.box(extents=[120, 120, 80])
    source = Source(position=[0, 0, 600], kind=kind,
                    **({"spectrum": {"kvp": 80.0, "filters": {"Al": 2.0}}} if kind == "point"
                       else {"energy": 50.0}))
    scene = Scene(source=source,
                  detector=Detector(center=[0, 0, -400], shape=(12, 10), pitch=(14.0, 14.0),
                                    supersample=2),
                  bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),
                          Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)")),
                  world={"material": AIR, "density": 0.05})
    with_world = xray_viz.render(scene, path_lengths=True)
    vacuum = xray_viz.render(scene.replace(world=None), path_lengths=True)
    assert (with_world.total_path_length == vacuum.total_path_length).all()
    rays = detector_rays(scene, supersample=2)
    from xray_viz.render import scene_projector
    L = scene_projector(scene, "numpy").path_lengths(scene.acquisition, supersample=2)
    outside = rays.t_max - L.sum(axis=1)
    assert outside.min() > 500                 # most of 1000 mm is world
    if kind == "parallel":
        assert rays.t_max == pytest.approx(np.full(len(rays.t_max), 1000.0))
    # one energy: each ray is exp(-mu_air * outside) times its vacuum transmission
    if kind == "parallel":
        ratio = with_world.intensity / vacuum.intensity
        per_pixel = np.exp(-_air_mu_per_mm(50.0, 0.05) * outside).reshape(-1, 4).mean(axis=1)
        # each pixel's four rays: same vacuum transmission where no edge crosses the pixel
        flat = ratio.ravel()
        assert np.median(np.abs(flat / per_pixel.reshape(flat.shape) - 1)) < 1e-12
    # the spectrum: the beam's sums with the world as one more body at the ray's outside path
    from xray_viz.physics.beam import Beam
    bodies = scene.bodies
    plain = Beam.of(scene.source, bodies, scene.detector).at(scene.acquisition)
    worldly = Beam.of(scene.source, bodies, scene.detector,
                      world=scene.world).at(scene.acquisition)
    air_as_body = Beam.of(scene.source, list(bodies) + [Body(
        name="air", mesh=slab, material=AIR, density=0.05)], scene.detector)
    got = worldly.log_transmission(L)
    want = air_as_body.log_transmission(np.column_stack([L, outside]))
    assert got == pytest.approx(want, rel=1e-12, abs=1e-14)
    assert (got < plain.log_transmission(L)).all()


def test_transport_primary_with_a_world_is_the_render_within_its_error():
    ball = trimesh.creation.icosphere(subdivisions=3, radius=30)
    slab = trimesh.creation.box(extents=[120, 120, 80])
    world = {"material": AIR, "density": 0.03}       # thin air would hide a missing term
    scene = Scene(source=Source(position=[0, 0, 600], energy=50.0),
                  detector=Detector(center=[0, 0, -400], shape=(8, 8), pitch=(15.0, 15.0),
                                    supersample=4),
                  bodies=(Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)"),
                          Body(name="water", mesh=slab, material="Water, Liquid")),
                  world=world)
    li = xray_viz.render(scene).line_integral
    li_vacuum = xray_viz.render(scene.replace(world=None)).line_integral
    assert (li - li_vacuum).min() > 0.5           # the world takes more than e^-0.5
    result = xray_viz.transport(scene, 100_000, seed=3)
    share = pixel_shares(scene.acquisition)
    expected = 50_000.0 * share * np.exp(-li)
    got, err = result.images["primary"], result.image_errors["primary"]
    seen = err > 0                       # a pixel behind the bone may score no primary
    assert seen.sum() >= 60
    z = (got - expected)[seen] / err[seen]
    assert abs(z.mean()) * np.sqrt(z.size) < 4 and np.abs(z).max() < 5
    total_err = np.sqrt((err ** 2).sum())
    assert abs(got.sum() - expected.sum()) < 4 * total_err
    # without the world's term the render would be far off
    wrong = 50_000.0 * share * np.exp(-li_vacuum)
    assert abs(got.sum() - wrong.sum()) > 20 * total_err
