"""The interactive viewer in a real X window (Xvfb), driven by real mouse and key events.

The other viewer tests call the widget callbacks directly and render off-screen; this one runs
``xray-viz show`` as a user would, on a virtual X display, clicks the radiograph and presses
the viewer's keys with xdotool (``.ci/system-deps`` installs Xvfb and xdotool).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.skipif(
    not (shutil.which("xvfb-run") and shutil.which("xdotool")),
    reason="needs xvfb-run and xdotool (installed by .ci/system-deps)")

# The window is 1400 x 700 at the top left of the virtual screen (no window manager); the
# radiograph fills the right half, its centre near (986, 272). The source-distance slider is the
# first of three in the upper row under it (viewer.SLIDER_COLUMNS: x 728 to 910, y 560), its
# knob at 0.26 of the way (the distance, 1500 mm, in a range of 450 to 4500 mm): x 775.
DRIVER = r"""
set -u
"$XRAY_VIZ" show sphere > viewer.log 2>&1 &
P=$!
xdotool search --sync --onlyvisible --name PyVista > /dev/null
sleep 3
xdotool mousemove 300 300 key i; sleep 2          # screenshot before picking: xray-viz-0.png
xdotool mousemove 986 272 click 1; sleep 3        # pick the centre pixel of the radiograph
xdotool mousemove 300 300 key i; sleep 2          # screenshot after picking: xray-viz-1.png
xdotool key b; sleep 2
xdotool key i; sleep 2                            # bodies close-up: xray-viz-2.png
xdotool mousemove 775 561 mousedown 1; sleep 0.5  # drag the source-distance knob to the right
xdotool mousemove 840 561; sleep 0.5
xdotool mousemove 905 561; sleep 0.5
xdotool mouseup 1; sleep 5
xdotool mousemove 300 300 key i; sleep 2          # source moved away: xray-viz-3.png
xdotool key q
for k in $(seq 30); do kill -0 $P 2>/dev/null || break; sleep 1; done
kill -0 $P 2>/dev/null && { echo "viewer still running after q" >> viewer.log; kill $P; }
wait $P
echo "exit $?" >> viewer.log
"""


def test_viewer_window_picks_a_pixel_switches_view_moves_the_source_and_quits(tmp_path):
    exe = Path(sys.executable).with_name("xray-viz")
    env = {"XRAY_VIZ": str(exe), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1600x900x24", "bash", "-c", DRIVER],
                   cwd=tmp_path, env=env, timeout=240, check=False, capture_output=True)
    log = (tmp_path / "viewer.log").read_text()
    assert log.strip().endswith("exit 0"), log          # q closed the window, exit status 0
    assert "Traceback" not in log, log
    shots = [tmp_path / f"xray-viz-{k}.png" for k in range(4)]
    assert all(p.is_file() for p in shots), log         # the i key saved four screenshots
    images = []
    for p in shots:
        with Image.open(p) as im:
            assert im.size == (1400, 700)
            images.append(np.asarray(im.convert("L"), dtype=float))
    before, picked, close_up, moved = images
    # picking draws the mu(t) chart in the lower left of the 3D pane, where there was none
    chart = (slice(400, 620), slice(140, 700))
    assert np.mean(np.abs(picked[chart] - before[chart]) > 40) > 0.02
    # the radiograph pane does not change (only a marker on the picked pixel)
    pane = (slice(90, 450), slice(810, 1160))
    assert np.mean(np.abs(picked[pane] - before[pane]) > 40) < 0.01
    # the b key moved the 3D camera: the upper 3D pane is a different picture
    upper = (slice(60, 400), slice(0, 640))
    assert np.mean(np.abs(close_up[upper] - picked[upper]) > 40) > 0.05
    # the sliders stay where they were, under the radiograph (VTK widgets must not take the
    # "i" key: it toggled them and brought them back in the 3D pane)
    band = (slice(460, 640), slice(700, 1400))
    assert np.mean(np.abs(close_up[band] - before[band]) > 40) < 0.005
    # dragging the source-distance knob moved the source away: a smaller shadow of the ball
    # (attenuation is shown bright on black)
    disc = [np.count_nonzero(im[pane] > 128) for im in (close_up, moved)]
    assert disc[1] < 0.8 * disc[0], disc



WALKTHROUGH_DRIVER = r"""
set -u
"$XRAY_VIZ" walkthrough 1 > walkthrough.log 2>&1 &
P=$!
for k in $(seq 90); do
  kill -0 $P 2>/dev/null || break
  W=$(xdotool search --onlyvisible --name "xray_viz walkthrough" 2>/dev/null | tail -1)
  if [ -n "$W" ]; then
    sleep 1
    echo "window: $(xdotool getwindowname $W)" >> windows.log
    xdotool mousemove 200 200 key q
  fi
  sleep 1
done
kill -0 $P 2>/dev/null && { echo "walkthrough still running" >> windows.log; kill $P; }
wait $P
echo "exit $?" >> windows.log
"""


def test_walkthrough_opens_windows_on_screen_and_ends_when_they_close(tmp_path):
    exe = Path(sys.executable).with_name("xray-viz")
    env = {"XRAY_VIZ": str(exe), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path),
           "XRAY_VIZ_OUTPUT": str(tmp_path / "pngs")}
    subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1600x900x24", "bash", "-c",
                    WALKTHROUGH_DRIVER], cwd=tmp_path, env=env, timeout=240, check=False,
                   capture_output=True)
    windows = (tmp_path / "windows.log").read_text()
    printed = (tmp_path / "walkthrough.log").read_text()
    assert windows.strip().endswith("exit 0"), windows + printed
    assert "window: xray_viz walkthrough 01: " in windows, windows
    assert "Traceback" not in printed
    assert "|r(t) - r0| = 6.0000" in printed          # the script ran to its end
    assert not list(tmp_path.rglob("*.png"))           # on screen: windows, not files
