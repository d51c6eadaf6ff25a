"""Smaller items of issue 43: a radiograph in a notebook (``plot``, ``_repr_png_``), scene files
written with relative mesh paths (``Scene.to_toml(path)``), walkthrough 8's words about its
own picture."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest

import xray_viz
from helpers import REPO

ROOT = REPO


@pytest.fixture(scope="module")
def sphere():
    return xray_viz.render(xray_viz.load_scene("sphere"))


def test_repr_png_is_the_radiograph_attenuation_bright(sphere):
    from PIL import Image

    shown = np.asarray(Image.open(io.BytesIO(sphere._repr_png_())))
    assert shown.shape == sphere.intensity.shape and shown.dtype == np.uint8
    # the ball (radius 40 mm, magnified 1.5: 120 px at 0.5 mm) white in the middle, the open
    # beam black; brighter where the chord is longer
    assert shown[128, 128] == 255 and shown[0, 0] == 0 and shown[5, 128] == 0
    assert shown[128, 128] > shown[128, 128 + 100] > shown[128, 128 + 125] == 0
    expected = np.round(255 * (sphere.intensity.max() - sphere.intensity)
                        / np.ptp(sphere.intensity))
    assert np.abs(shown - expected).max() <= 1


def test_plot_draws_the_quantity_in_mm(sphere):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    try:
        image = sphere.plot(ax=ax)
        assert np.array_equal(np.asarray(image.get_array()), sphere.intensity)
        assert image.get_cmap().name == "gray_r"            # attenuation bright
        assert image.get_extent() == pytest.approx([-64.0, 64.0, -64.0, 64.0])   # 256 x 0.5 mm
        li = sphere.plot("line-integral", ax=ax, colorbar=False)
        assert np.array_equal(np.asarray(li.get_array()), sphere.line_integral)
    finally:
        plt.close(fig)


def test_to_toml_with_a_path_writes_mesh_paths_relative_to_it(tmp_path):
    scene = xray_viz.load_scene("nested_spheres")
    out = tmp_path / "copy" / "scene.toml"
    out.parent.mkdir()
    text = scene.to_toml(out)
    assert out.read_text(encoding="utf-8") == text
    meshes = [line.split("=", 1)[1].strip().strip('"') for line in text.splitlines()
              if line.startswith("mesh")]
    assert len(meshes) == 3 and not any(os.path.isabs(m) for m in meshes), meshes
    assert all((out.parent / m).resolve().is_file() for m in meshes)
    again = xray_viz.load_scene(out)
    assert np.array_equal(xray_viz.render(again).intensity, xray_viz.render(scene).intensity)
    assert [p for p in out.parent.iterdir()] == [out]        # no temporary left


def test_walkthrough_8_says_what_its_picture_shows():
    """The radiograph is drawn attenuation bright: the air bubble lets more through than the
    bone around it, so it is a darker disc there, and the text says so."""
    text = (ROOT / "apps" / "walkthroughs" / "08_radiograph.py").read_text(encoding="utf-8")
    assert "*darker* disc" in text and "brighter* disc" not in text
    image = xray_viz.render(xray_viz.load_scene("nested_spheres"))
    shown = image.display()
    # bubble r = 10 mm, bone r = 25 mm, magnification 1.5, pitch 0.5 mm: 30 px and 75 px
    bubble, bone = shown[128, 128], shown[128, 128 + 50]
    assert bubble < bone
    # the picture drawn attenuation bright: the bubble lets more through than the bone around it
    assert image.intensity[128, 128] > image.intensity[128, 128 + 50]


def test_mesh_reports_overlapping_pieces_and_their_union(tmp_path):
    """Two overlapping boxes in one file: the render fills their union (8 + 8 - 2.625 mm^3),
    and `xray-viz mesh` says so, with the faces where the pieces cross."""
    import trimesh

    from xray_viz.cli import main

    a = trimesh.creation.box(extents=[20.0, 20.0, 20.0])
    b = a.copy()
    b.apply_translation([10.0, 5.0, 2.5])
    trimesh.util.concatenate([a, b]).export(tmp_path / "two.stl")
    out = io.StringIO()
    from contextlib import redirect_stdout

    with redirect_stdout(out):
        assert main(["mesh", str(tmp_path / "two.stl"), "-o", str(tmp_path / "fixed.stl")]) == 0
    text = out.getvalue()
    rows = {line[:24].strip(): line[24:].split() for line in text.splitlines()}
    volume = float(rows["volume (mm^3)"][-1])
    assert volume == pytest.approx(16000.0 - 10.0 * 15.0 * 17.5, rel=2e-3), text   # 13375
    assert int(rows["self-intersecting faces"][-1]) > 0, text
    assert "the render fills their union" in text
    # the same volume as the render's: a parallel beam's path lengths over the detector
    from xray_viz.meshes.command import union_volume

    assert union_volume(trimesh.load(tmp_path / "fixed.stl")) == pytest.approx(volume, rel=1e-5)


def test_mesh_of_one_piece_reports_as_before(tmp_path):
    import trimesh

    from xray_viz.cli import main

    trimesh.creation.box(extents=[20.0, 20.0, 20.0]).export(tmp_path / "one.stl")
    out = io.StringIO()
    from contextlib import redirect_stdout

    with redirect_stdout(out):
        assert main(["mesh", str(tmp_path / "one.stl"), "-o", str(tmp_path / "f.stl")]) == 0
    text = out.getvalue()
    assert "overlap" not in text and "8000" in text


def test_a_metal_implant_does_not_take_the_png_window(tmp_path):
    """The limb with a steel rod (4 mm across, 60 mm long) beside the radius: the line-integral
    PNG's window spans the forearm's values, the rod's pixels are drawn saturated at its top
    (counted in the window as ``clipped``), and the forearm's values read back within half a
    quantisation step; without the rod, the window is the image's whole range as before."""
    import trimesh

    limb = xray_viz.load_scene("limb")
    rod = trimesh.creation.cylinder(radius=2.0, height=60.0, sections=48)
    rod.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    rod.apply_translation([-12.0, 0.0, 0.0])
    rod.export(tmp_path / "rod.stl")
    text = limb.to_toml() + ('\n[[body]]\nname = "rod"\nmesh = "rod.stl"\nmaterial = "Fe"\n'
                             'density = 7.87\n')
    (tmp_path / "implant.toml").write_text(text)
    with_rod = xray_viz.load_scene(tmp_path / "implant.toml")
    li = xray_viz.render(with_rod).line_integral
    body = xray_viz.render(limb).line_integral
    out = xray_viz.save_image(tmp_path / "li.png", li, quantity="line-integral")
    stored, meta = xray_viz.load_image(out, with_metadata=True)
    window = meta.window
    rod_pixels = li > body.max() * 1.25
    assert 50 < rod_pixels.sum() < 0.01 * li.size
    assert body.max() <= window["high"] < li[rod_pixels].min() < li.max()
    assert window["clipped"] == int((li > window["high"]).sum())
    assert (stored[rod_pixels] == 65535).all()
    kept = li <= window["high"]
    assert np.abs(meta.to_physical(stored)[kept] - li[kept]).max() <= window["step"] / 2 * 1.001
    plain = xray_viz.load_image(xray_viz.save_image(tmp_path / "body.png", body,
                                                    quantity="line-integral"),
                                with_metadata=True)[1].window
    assert (plain["low"], plain["high"]) == (body.min(), body.max()) and "clipped" not in plain
