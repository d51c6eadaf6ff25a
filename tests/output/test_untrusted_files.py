"""Files from elsewhere: a container never hands out another file's bytes, and no error message
quotes a line of a file that is not the scene itself.

* HDF5 (``load_image`` of a ``.h5``): an external link, external raw storage or a virtual
  dataset pointing at a secret file is refused in one line (on the old code each returned the
  secret file's contents as the image).
* MetaImage ``.mhd`` / detached NRRD ``.nhdr`` (``[[labels]]``, ``[[ct]]``, ``xray-viz mesh``): a
  data file named outside the header's own folder (an absolute path, ``..``) is refused.
* A file named as a spectrum, a mesh, a material table...: its content is never echoed in
  an error (the secret's text, planted on a line of its own, never appears), also when the
  scene comes embedded in an image.
"""

from __future__ import annotations

import numpy as np
import pytest

from xray_viz.errors import XrayVizError

h5py = pytest.importorskip("h5py")

SECRET = "FAKESECRET-7f3a9c1d2e"


@pytest.fixture
def secret_files(tmp_path):
    """A secret HDF5 file (a 3x3 image of 42) and a secret text file, beside the crafted ones."""
    with h5py.File(tmp_path / "secret.h5", "w") as f:
        f["data"] = np.full((3, 3), 42.0)
    (tmp_path / "secret.txt").write_bytes(f"{SECRET}\n".encode() * 4)
    return tmp_path


def _crafted_h5(tmp_path, kind: str):
    path = tmp_path / f"{kind}.h5"
    with h5py.File(path, "w") as f:
        if kind == "external-link":
            f["entry/instrument/detector/data"] = h5py.ExternalLink("secret.h5", "/data")
        elif kind == "external-link-nested":
            f.create_group("a/b")
            f["a/b/image"] = h5py.ExternalLink(str(tmp_path / "secret.h5"), "/data")
        elif kind == "external-storage":
            f.create_dataset("image", shape=(2, 8), dtype="u1",
                             external=[("secret.txt", 0, 16)])
        elif kind == "virtual":
            layout = h5py.VirtualLayout(shape=(3, 3), dtype="f8")
            layout[:] = h5py.VirtualSource("secret.h5", "/data", shape=(3, 3))
            f.create_virtual_dataset("image", layout)
        elif kind == "metadata-link":             # the image inside, its metadata outside
            f["entry/instrument/detector/data"] = np.ones((2, 2))
            f["entry/xray_viz_metadata"] = h5py.ExternalLink("secret.h5", "/data")
    return path


@pytest.mark.parametrize("kind", ["external-link", "external-link-nested", "external-storage",
                                  "virtual", "metadata-link"])
def test_load_image_h5_refuses_other_files(secret_files, kind):
    from xray_viz.output import OutputError, load_image

    path = _crafted_h5(secret_files, kind)
    with pytest.raises(OutputError) as err:
        load_image(path)
    message = str(err.value)
    assert "\n" not in message and str(path) in message and "refused" in message
    assert SECRET not in message


def test_load_image_h5_inside_links_still_read(tmp_path):
    """Soft links inside the file (NeXus uses them) and plain datasets are read as before."""
    from xray_viz.output import load_image

    path = tmp_path / "soft.h5"
    with h5py.File(path, "w") as f:
        f["raw/frame"] = np.arange(6.0).reshape(2, 3)
        f["entry/instrument/detector/data"] = h5py.SoftLink("/raw/frame")
    np.testing.assert_array_equal(load_image(path), np.arange(6.0).reshape(2, 3))


LABELS = np.zeros((6, 6, 6), dtype=np.uint8)
LABELS[1:5, 1:5, 1:5] = 1


def _write_mhd(header_dir, data_name: str, raw_path):
    raw_path.parent.mkdir(parents=True, exist_ok=True)
    LABELS.transpose(2, 1, 0).tofile(raw_path)
    header = header_dir / "labels.mhd"
    header.write_text("ObjectType = Image\nNDims = 3\nDimSize = 6 6 6\n"
                      "ElementSpacing = 1 1 1\nElementType = MET_UCHAR\n"
                      f"ElementDataFile = {data_name}\n")
    return header


def _write_nhdr(header_dir, data_name: str, raw_path):
    raw_path.parent.mkdir(parents=True, exist_ok=True)
    LABELS.transpose(2, 1, 0).tofile(raw_path)
    header = header_dir / "labels.nhdr"
    header.write_text("NRRD0004\ntype: uint8\ndimension: 3\nsizes: 6 6 6\n"
                      "spacings: 1 1 1\nencoding: raw\n"
                      f"data file: {data_name}\n")
    return header


@pytest.mark.parametrize("write", [_write_mhd, _write_nhdr])
def test_detached_data_file_stays_beside_its_header(tmp_path, write):
    """A header naming its data file outside its own folder is refused; beside it, read."""
    pytest.importorskip("SimpleITK")
    from xray_viz.meshes.volumes import read_volume

    here = tmp_path / "scene"
    here.mkdir()
    elsewhere = tmp_path / "elsewhere" / "labels.raw"
    for name in ("../elsewhere/labels.raw", str(elsewhere)):
        header = write(here, name, elsewhere)
        with pytest.raises(XrayVizError) as err:
            read_volume(header)
        message = str(err.value)
        assert "\n" not in message and str(header) in message and "outside" in message
    header = write(here, "data/labels.raw", here / "data" / "labels.raw")
    volume = read_volume(header)
    assert int(np.asarray(volume.data).sum()) == int(LABELS.sum())


SCENE = ('[source]\nposition = [0.0, 0.0, 1000.0]\n{source}\n'
         '[detector]\ncenter = [0.0, 0.0, -500.0]\nshape = [16, 16]\npitch = [8.0, 8.0]\n{detector}\n'
         '{bodies}')
BALL = '[[body]]\nname = "ball"\nphantom = "sphere"\n'

#: What a private file may look like: the secret on its first line, on its second, quoted.
CONTENTS = {
    "line-1": f"{SECRET}\n1 2\n",
    "line-2": f"energy,fluence\n{SECRET},3\n5 6\n",
    "quoted": f"1,2\n'{SECRET}' \"{SECRET}\" `{SECRET}`\n",
}


def _scenes(secret_file):
    """Every way a scene names a file that is not itself: (what, scene text)."""
    f = secret_file.as_posix()
    ball = f'[[body]]\nname = "ball"\nmesh = "{_ball(secret_file.parent)}"\nmu = 0.2\n'
    yield "spectrum", SCENE.format(source=f'spectrum = {{ file = "{f}" }}', detector="",
                                   bodies=ball)
    for key in ("file", "lsf"):
        yield f"mtf {key}", SCENE.format(source="energy = 60.0",
                                         detector=f'mtf = {{ {key} = "{f}" }}', bodies=ball)
    for suffix in (".stl", ".obj", ".ply", ".off", ".gltf", ".vtk", ".vtp"):
        mesh = secret_file.with_suffix(suffix)
        mesh.write_bytes(secret_file.read_bytes())
        yield f"mesh {suffix}", SCENE.format(
            source="energy = 60.0", detector="",
            bodies=f'[[body]]\nname = "b"\nmesh = "{mesh.as_posix()}"\nmu = 0.2\n')
    for suffix in (".mhd", ".nhdr", ".nrrd", ".nii"):
        vol = secret_file.with_suffix(suffix)
        vol.write_bytes(secret_file.read_bytes())
        for table, extra in (("labels", 'materials = { 1 = "Water, Liquid" }\n'), ("ct", "")):
            yield f"{table} {suffix}", SCENE.format(
                source="energy = 60.0", detector="",
                bodies=f'[[{table}]]\nfile = "{vol.as_posix()}"\n{extra}')


def _ball(folder):
    import trimesh

    path = folder / "ball.stl"
    if not path.exists():
        trimesh.creation.icosphere(subdivisions=2, radius=20.0).export(path)
    return path.as_posix()


@pytest.mark.parametrize("content", sorted(CONTENTS))
def test_no_error_quotes_a_file_that_is_not_the_scene(tmp_path, content):
    """A private file named as a spectrum, an MTF/LSF table, a mesh of every format or a
    volume: the error names the file (and a line or field), never what it holds."""
    from xray_viz.scene import load_scene

    secret_file = tmp_path / "private.csv"
    secret_file.write_text(CONTENTS[content])
    tried = 0
    for what, text in _scenes(secret_file):
        scene = tmp_path / "scene.toml"
        scene.write_text(text)
        try:
            load_scene(scene)        # a secret's first line may pass for a spectrum's header
        except XrayVizError as err:
            message = str(err)
            assert SECRET[:10] not in message, (what, message)
            assert "\n" not in message
            tried += 1
    assert tried >= 17


@pytest.mark.parametrize("suffix", [".npy", ".tiff", ".png", ".h5", ".nii", ".nii.gz", ".dcm"])
def test_load_image_does_not_quote_a_file(tmp_path, suffix):
    from xray_viz.output import OutputError, load_image

    for content in CONTENTS.values():
        path = tmp_path / f"private{suffix}"
        path.write_text(content)
        with pytest.raises(OutputError) as err:
            load_image(path)
        assert SECRET[:10] not in str(err.value), str(err.value)


def test_embedded_scene_does_not_quote_its_files(tmp_path):
    """An image's embedded scene names a spectrum file: once that file is replaced by a private
    one, rebuilding the scene from the image names the file, never its text."""
    from xray_viz.output import load_image, save_image
    from xray_viz.scene import load_scene

    spectrum = tmp_path / "spectrum.csv"
    spectrum.write_text("keV,fluence\n30,1\n50,2\n60,1\n")
    (tmp_path / "scene.toml").write_text(SCENE.format(
        source=f'spectrum = {{ file = "{spectrum.as_posix()}" }}', detector="",
        bodies=f'[[body]]\nname = "ball"\nmesh = "{_ball(tmp_path)}"\nmu = 0.2\n'))
    scene = load_scene(tmp_path / "scene.toml")
    out = save_image(tmp_path / "image.png", np.zeros((16, 16)), scene=scene,
                     quantity="line-integral")
    _, meta = load_image(out, with_metadata=True)
    assert meta.scene().source.spectrum is not None
    spectrum.write_text(CONTENTS["line-2"])
    with pytest.raises(XrayVizError) as err:
        meta.scene()
    assert str(spectrum) in str(err.value) and "line 2" in str(err.value)
    assert SECRET[:10] not in str(err.value)
