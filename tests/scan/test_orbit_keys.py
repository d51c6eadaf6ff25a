"""Orbit keys that do not apply (issue 42): a helical orbit without a pitch (a circle) and a
circular orbit given a pitch were accepted without a word - the CLI's ``--pitch`` was dropped
for ``--orbit circular``; ``arc``/``pitch``/``start`` on a poses orbit were ignored. Each is
now one line naming the key."""

from __future__ import annotations

import pytest

from xray_viz.cli import main
from xray_viz.errors import SceneError
from xray_viz.orbit import orbit_from_dict


@pytest.mark.parametrize("table, words", [
    ({"orbit": "helical", "projections": 8}, "helical\" needs pitch"),
    ({"orbit": "helical", "projections": 8, "pitch": 0.0}, "helical\" needs pitch"),
    ({"orbit": "circular", "projections": 8, "pitch": 5.0}, "pitch = 5 needs orbit"),
    ({"poses": {"random": 4, "seed": 1}, "arc": 90.0}, "arc = 90.0 does not apply"),
    ({"poses": {"random": 4, "seed": 1}, "pitch": 3.0}, "pitch = 3.0 does not apply"),
    ({"orbit": "poses", "poses": {"random": 4, "seed": 1}, "start": 10.0},
     "start = 10.0 does not apply"),
])
def test_orbit_keys_that_do_not_apply(table, words):
    with pytest.raises(SceneError, match=words) as err:
        orbit_from_dict(table, file="scene.toml")
    assert str(err.value).startswith("scene.toml: [scan]") and "\n" not in str(err.value)


def test_orbits_that_apply_still_load():
    assert orbit_from_dict({"orbit": "helical", "projections": 8, "pitch": 10.0}).pitch == 10.0
    assert orbit_from_dict({"orbit": "circular", "projections": 8, "pitch": 0.0}).pitch == 0.0
    assert orbit_from_dict({"poses": {"random": 4, "seed": 1}}).projections == 4


@pytest.mark.parametrize("argv, words", [
    (["--orbit", "circular", "--pitch", "10"], "--pitch 10 does not apply to --orbit circular"),
    (["--orbit", "helical", "--pitch", "0"], "needs pitch"),
])
def test_cli_orbit_options_that_do_not_apply(tmp_path, capsys, argv, words):
    out = tmp_path / "s.zarr"
    assert main(["scan", "sphere", "-o", str(out), "--projections", "2", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0], err
    assert not out.exists()
