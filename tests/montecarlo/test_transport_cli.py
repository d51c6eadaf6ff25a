"""``xray-viz dose`` and the transport on Dask: the same numbers bit for bit, bad input in one
line with exit 2, the output written safely."""

from __future__ import annotations

import json

import pytest
import trimesh

import xray_viz
from xray_viz.cli import main

SCENE = """
[source]
position = [0, 0, 600]
energy = 60.0
{mas}
[detector]
center = [0, 0, -400]
shape = [16, 16]
pitch = 8.0
{world}
[[body]]
name = "water"
mesh = "slab.stl"
material = "{material}"
{density}
[[body]]
name = "bone"
mesh = "ball.stl"
material = "Bone, Cortical (ICRP)"
"""


def _write_scene(tmp_path, *, world='[world]\nmaterial = "Air, Dry (near sea level)"',
                 material="Water, Liquid", density="", mas="", name="scene.toml"):
    trimesh.creation.box(extents=[120, 120, 80]).export(tmp_path / "slab.stl")
    trimesh.creation.icosphere(subdivisions=2, radius=30).export(tmp_path / "ball.stl")
    path = tmp_path / name
    path.write_text(SCENE.format(world=world, material=material, density=density, mas=mas))
    return path


def test_dose_prints_and_writes_the_apis_numbers(tmp_path, capsys):
    scene = _write_scene(tmp_path)
    out = tmp_path / "dose.json"
    assert main(["dose", str(scene), "--histories", "20000", "--seed", "3", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "water" in printed and "bone" in printed and "escaped" in printed
    doc = json.loads(out.read_text())
    api = xray_viz.transport(xray_viz.load_scene(scene), 20000, seed=3)
    assert {r["body"]: r["energy_eV_per_history"] for r in doc["bodies"]} == api.energy
    assert doc["histories"] == 20000 and doc["balance"] == api.balance
    csv = tmp_path / "dose.csv"
    assert main(["dose", str(scene), "--histories", "20000", "--seed", "3", "-o", str(csv)]) == 0
    lines = csv.read_text().splitlines()
    assert lines[0].startswith("body,energy_eV_per_history") and len(lines) == 3
    assert float(lines[1].split(",")[1]) == api.energy["water"]


def test_dose_with_mas_reports_gray(tmp_path, capsys):
    scene = _write_scene(tmp_path, mas="mas = 10.0",
                         world="").read_text().replace("energy = 60.0",
                                                      "spectrum = { kvp = 80.0, filters = { Al = 2.5 } }")
    path = tmp_path / "mas.toml"
    path.write_text(scene)
    result = xray_viz.transport(xray_viz.load_scene(path), 20000, seed=1)
    assert set(result.dose) == {"water", "bone"}
    assert all(0 < d < 1 for d in result.dose.values())     # mGy-scale for 10 mAs
    # dose = energy x photons / mass: the ratio of two bodies' doses is that of energy/mass
    vol_ball = trimesh.creation.icosphere(subdivisions=2, radius=30).volume
    vol_slab = 120 * 120 * 80 - vol_ball
    m_bone, m_water = vol_ball * 1.85e-6, vol_slab * 1.0e-6      # kg
    ratio = (result.energy["bone"] / m_bone) / (result.energy["water"] / m_water)
    assert result.dose["bone"] / result.dose["water"] == pytest.approx(ratio, rel=1e-6)


@pytest.mark.parametrize("args, kind, match", [
    (["--histories", "0"], {}, "--histories must be > 0"),
    (["--histories", "-3"], {}, "--histories must be > 0"),
    (["--histories", "10"], {"world": '[world]\nmaterial = "Vacuumium"'}, "[world] unknown"),
    (["--histories", "10"], {"material": "H2O"}, "give its density"),
    (["--histories", "10", "-o", "x.txt"], {}, "end it in .csv or .json"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, capsys, args, kind, match):
    scene = _write_scene(tmp_path, **kind)
    keep = tmp_path / "previous.json"
    keep.write_text("{}")
    extra = [] if "-o" in args else ["-o", str(keep)]
    assert main(["dose", str(scene), *args, *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err and "Traceback" not in err
    assert keep.read_text() == "{}"                  # nothing half-written, nothing lost


def test_no_detector_is_one_line(tmp_path, capsys):
    scene = _write_scene(tmp_path)
    text = scene.read_text()
    start = text.index("[detector]")
    scene.write_text(text[:start] + text[text.index("[world]"):])
    assert main(["dose", str(scene), "--histories", "10"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "detector" in err


def test_dask_local_cluster_gives_the_serial_bits(tmp_path):
    from distributed import Client

    from xray_viz.scan import local_cluster

    scene = xray_viz.load_scene(_write_scene(tmp_path))
    # batches of 256: 12000 histories are 47 batches in 3 groups (Dask tasks)
    serial = xray_viz.transport(scene, 12000, seed=9, batch=256)
    with local_cluster(2) as cluster, Client(cluster) as client:
        assert client.scheduler_info()["address"].startswith("tcp://127.0.0.1")
        assert len(client.scheduler_info()["workers"]) == 2
        dask = xray_viz.transport(scene, 12000, seed=9, batch=256, client=client)
        # the command line on the same cluster (--scheduler ADDR), default batches
        out = tmp_path / "dask.json"
        assert main(["dose", str(scene.path), "--histories", "12000", "--seed", "9",
                     "--scheduler", cluster.scheduler_address, "-o", str(out)]) == 0
    cli = {r["body"]: r["energy_eV_per_history"] for r in json.loads(out.read_text())["bodies"]}
    assert cli == xray_viz.transport(scene, 12000, seed=9).energy
    assert dask.energy == serial.energy and dask.energy_error == serial.energy_error
    assert dask.balance == serial.balance
    assert all((dask.images[k] == serial.images[k]).all() for k in serial.images)
