"""Special files and silent mappings (issue 42).

* A named pipe (FIFO) given where a file is read - a mesh, an image, a volume, a spectrum or
  MTF table, a scene (TOML or gVXR JSON), a poses file - blocked the reader for ever; now it is
  refused in one line at once. (Siblings: every reader of a path a user names; a DICOM series
  folder already skips what is not a regular file.)
* ``save_image`` to DICOM stored NaN and inf as the window's ends without a word; now it warns
  as a PNG does (the TIFF, NIfTI, HDF5 and ``.npy`` formats keep them as they are).
"""

from __future__ import annotations

import os
import threading

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import XrayVizError

HEAD = ('[source]\nposition = [0.0, 0.0, 1000.0]\n{source}\n[detector]\n'
        'center = [0.0, 0.0, -500.0]\nshape = [8, 8]\npitch = [8.0, 8.0]\n{detector}\n')


def _call_with_fifo(fifo, call, timeout=20.0):
    """``call()`` in a thread: what it raised; a call still blocked after ``timeout`` fails the
    test (and is released by opening the FIFO for writing, so the thread ends)."""
    out = {}

    def run():
        try:
            call()
        except BaseException as exc:      # noqa: BLE001 - handed to the test
            out["exc"] = exc

    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(timeout)
    if t.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        t.join(10)
        pytest.fail(f"reading the FIFO {fifo.name} blocked for more than {timeout:g} s")
    return out.get("exc")


def _cases(tmp_path):
    from xray_viz.meshes.io import load_mesh
    from xray_viz.meshes.volumes import read_volume
    from xray_viz.orbit import read_poses
    from xray_viz.output import load_image
    from xray_viz.physics.spectra import read_spectrum_csv
    from xray_viz.scene import load_scene

    ball = tmp_path / "ball.stl"
    import trimesh

    trimesh.creation.icosphere(subdivisions=1, radius=10.0).export(ball)

    def scene_naming(name, source="energy = 60.0", detector="", body=True):
        def load():
            s = tmp_path / f"{name}.toml"
            text = HEAD.format(source=source, detector=detector)
            if body:
                text += f'[[body]]\nname = "b"\nmesh = "{ball.as_posix()}"\nmu = 0.2\n'
            s.write_text(text)
            load_scene(s)
        return load

    def fifo(name):
        path = tmp_path / name
        os.mkfifo(path)
        return path

    yield "mesh", (f := fifo("pipe.stl")), lambda: load_mesh(f)
    yield "mesh in a scene", (g := fifo("pipe2.obj")), lambda: _scene_with_mesh(tmp_path, g)
    for suffix in (".png", ".tiff", ".npy", ".h5", ".nii", ".dcm"):
        p = fifo(f"pipe{suffix}")
        yield f"image {suffix}", p, (lambda p=p: load_image(p))
    for suffix in (".nii.gz", ".mha", ".nrrd"):
        p = fifo(f"vol{suffix}")
        yield f"volume {suffix}", p, (lambda p=p: read_volume(p))
    p = fifo("spectrum.csv")
    yield "spectrum", p, lambda p=p: read_spectrum_csv(p)
    p = fifo("mtf.csv")
    yield "mtf", p, scene_naming("mtf", detector=f'mtf = {{ file = "{p.as_posix()}" }}')
    p = fifo("scene.toml")
    yield "scene", p, lambda p=p: load_scene(p)
    p = fifo("scene.json")
    yield "gVXR scene", p, lambda p=p: load_scene(p)
    p = fifo("poses.json")
    yield "poses", p, lambda p=p: read_poses(p)


def _scene_with_mesh(tmp_path, mesh):
    from xray_viz.scene import load_scene

    s = tmp_path / "with_mesh.toml"
    s.write_text(HEAD.format(source="energy = 60.0", detector="")
                 + f'[[body]]\nname = "b"\nmesh = "{mesh.as_posix()}"\nmu = 0.2\n')
    load_scene(s)


def test_a_fifo_is_refused_not_read(tmp_path):
    seen = 0
    for what, fifo, call in _cases(tmp_path):
        exc = _call_with_fifo(fifo, call)
        assert isinstance(exc, XrayVizError), (what, exc)
        message = str(exc)
        assert "is not a regular file" in message and fifo.name in message, (what, message)
        assert "\n" not in message
        seen += 1
    assert seen == 16


def test_dicom_warns_about_non_finite_pixels(tmp_path):
    from xray_viz.output import load_image, save_image

    scene = xray_viz.load_scene("sphere")
    image = np.linspace(0.0, 3.0, 40).reshape(5, 8)
    image[0, 0], image[1, 1], image[2, 2] = np.inf, np.nan, -np.inf
    with pytest.warns(RuntimeWarning, match=r"x\.dcm: 3 of 40 pixels are not finite") as got:
        save_image(tmp_path / "x.dcm", image, scene=scene, quantity="line-integral")
    assert len(got) == 1
    back = load_image(tmp_path / "x.dcm")
    finite = np.isfinite(image)
    assert back[0, 0] == pytest.approx(image[finite].max())      # +inf: the window's top
    assert back[1, 1] == pytest.approx(image[finite].min())      # NaN: its bottom
    clean = np.where(finite, image, 1.0)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")                # a finite image: no warning
        save_image(tmp_path / "y.dcm", clean, scene=scene, quantity="line-integral")
