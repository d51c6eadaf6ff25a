"""``xray-viz show SCENE --web``: the viewer on a trame server, driven in headless Chromium.

The server runs as a subprocess bound to 127.0.0.1 on a free port (it prints its URL); Debian's
``chromium`` (``.ci/system-deps``) is driven through the DevTools protocol by playwright's Python
package, with ``executable_path`` (playwright downloads no browser). Every request of the page
that is not for 127.0.0.1 is recorded and refused: the viewer must work off-line.

The helpers here (:func:`browser_page`, :func:`view_region`, :func:`magenta_fraction`) are also
used by ``test_notebook_viewer.py``.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np
import pytest
from PIL import Image

from helpers import REPO

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
LOCAL_HOSTS = ("127.0.0.1", "localhost")

needs_browser = pytest.mark.skipif(
    CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/system-deps when root)")

#: Where the screenshots go, to be looked at (kept when XRAY_VIZ_SCREENSHOTS names a folder).
SHOTS = os.environ.get("XRAY_VIZ_SCREENSHOTS")


@contextlib.contextmanager
def browser_page(viewport=(1400, 900)):
    """A page of headless Chromium; ``page.remote`` lists the requests refused (not local)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=[
            "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run"])
        try:
            context = browser.new_context(viewport={"width": viewport[0], "height": viewport[1]})
            remote = []

            def guard(route):
                url = route.request.url
                if urlsplit(url).scheme in ("http", "https", "ws", "wss") \
                        and urlsplit(url).hostname not in LOCAL_HOSTS:
                    remote.append(url)
                    route.abort()
                else:
                    route.continue_()

            context.route("**/*", guard)
            page = context.new_page()
            page.remote = remote
            yield page
        finally:
            browser.close()


def save_shot(page_or_locator, tmp_path, name) -> np.ndarray:
    """Screenshot as an RGB array, written to tmp_path (and to $XRAY_VIZ_SCREENSHOTS)."""
    path = tmp_path / f"{name}.png"
    page_or_locator.screenshot(path=str(path))
    if SHOTS:
        Path(SHOTS).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(SHOTS) / path.name)
    return np.asarray(Image.open(path).convert("RGB"), dtype=float)


def view_region(shot: np.ndarray, half: str) -> np.ndarray:
    """The left (3D scene) or right (radiograph) half of a screenshot of the render view."""
    w = shot.shape[1]
    return shot[:, : w // 2] if half == "3d" else shot[:, w // 2:]


def non_background(region: np.ndarray) -> float:
    """Fraction of pixels that are not the white background."""
    return float((region.min(axis=2) < 235).mean())


def magenta_fraction(region: np.ndarray) -> float:
    """Fraction of magenta(-ish) pixels: the picked ray (a thin line, blended with the yellow
    rays by the stream's JPEG) and the picked pixel's outline."""
    r, g, b = region[..., 0], region[..., 1], region[..., 2]
    return float(((r > 150) & (b > 120) & (b - g > 60) & (r - g > 60)).mean())


def wait_for_text(locator, pattern, timeout=60.0) -> str:
    """Wait until the element's text matches ``pattern``; return it."""
    end = time.monotonic() + timeout
    text = ""
    while time.monotonic() < end:
        text = locator.inner_text()
        if re.search(pattern, text):
            return text
        time.sleep(0.2)
    raise AssertionError(f"{pattern!r} never appeared; the text is {text!r}")


def wait_for_shot(view, tmp_path, name, done, timeout=60.0) -> np.ndarray:
    """Screenshots of the render view until ``done(shot)`` (the server's next picture is in)."""
    end = time.monotonic() + timeout
    while True:
        shot = save_shot(view, tmp_path, name)
        if done(shot) or time.monotonic() > end:
            return shot
        time.sleep(0.25)


def drive_viewer(page, tmp_path, prefix: str, frame=None) -> dict:
    """Move the source-distance slider, click the radiograph's centre, screenshot each step.

    ``frame`` is where the viewer's page is (the page itself, or the notebook's iframe).
    Returns the screenshots and the texts the page showed.
    """
    doc = frame or page
    view = doc.locator("#xray-viz-view")
    view.locator("img").first.wait_for(timeout=60_000)
    first = wait_for_shot(view, tmp_path, f"{prefix}-0-loaded",
                          lambda shot: non_background(view_region(shot, "3d")) > 0.01)
    status = doc.locator("#xray-viz-status")
    before = status.inner_text()
    slider = doc.locator("#slider-source_distance")
    old = float(slider.input_value())
    slider.focus()
    page.keyboard.press("PageDown")                  # a tenth of the range, nearer the detector
    new = float(slider.input_value())
    after = wait_for_text(status, r"source %d mm" % round(new))
    moved = wait_for_shot(view, tmp_path, f"{prefix}-1-slider",
                          lambda shot: np.abs(shot - first).mean() > 1.0)
    box = view.bounding_box()
    # the radiograph's centre in the viewer's layout (right pane, above the slider band)
    page.mouse.click(box["x"] + 0.712 * box["width"], box["y"] + 0.39 * box["height"])
    picked = wait_for_text(doc.locator("#xray-viz-picked"), r"pixel \(\d+, \d+\)")
    clicked = wait_for_shot(view, tmp_path, f"{prefix}-2-picked",
                            lambda shot: magenta_fraction(view_region(shot, "3d")) > 2e-4)
    save_shot(page, tmp_path, f"{prefix}-3-page")       # the whole page, controls included
    return {"first": first, "moved": moved, "clicked": clicked, "old": old, "new": new,
            "before": before, "status": after, "picked": picked}


def check_driven(result, shape, integral_near=None):
    """What both tests assert about a driven viewer (``shape``: the preview's pixels;
    ``integral_near``: the analytic line integral of the centre ray, when known)."""
    first, moved, clicked = result["first"], result["moved"], result["clicked"]
    # the render view is not empty: a drawing in the 3D pane, the radiograph in the other
    for shot in (first, moved, clicked):
        assert shot.std() > 20
        assert 0.02 < non_background(view_region(shot, "3d")) < 0.7
        assert non_background(view_region(shot, "radiograph")) > 0.1
    # the slider moved the source: its value, the viewer's status line and the picture
    assert result["new"] < result["old"]
    m = re.search(r"source (\d+) mm", result["status"])
    assert m and float(m.group(1)) == pytest.approx(result["new"], abs=1)
    assert np.abs(moved - first).mean() > 1.0
    # the click picked a pixel near the radiograph's centre, and its ray is drawn (magenta)
    m = re.search(r"pixel \((\d+), (\d+)\): integral mu dt = ([\d.e+-]+)", result["picked"])
    assert m, result["picked"]
    i, j, integral = int(m.group(1)), int(m.group(2)), float(m.group(3))
    w, h = shape
    assert abs(i - (w - 1) / 2) < 0.15 * w and abs(j - (h - 1) / 2) < 0.15 * h
    assert integral > 0                                 # the centre ray crosses the body
    if integral_near is not None:
        assert integral == pytest.approx(integral_near, rel=0.02)
    assert magenta_fraction(view_region(moved, "3d")) < 1e-4
    assert magenta_fraction(view_region(clicked, "3d")) > 2e-4
    assert magenta_fraction(view_region(clicked, "radiograph")) > 1e-5


@contextlib.contextmanager
def web_server(*args, timeout=240):
    """``xray-viz show ... --web`` as a subprocess; yields (process, url). Stops it by SIGINT."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("DISPLAY", None)
    proc = subprocess.Popen([sys.executable, "-m", "xray_viz", "show", *args, "--web"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=REPO)
    try:
        url = None
        end = time.monotonic() + timeout
        lines = []
        while time.monotonic() < end:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            m = re.search(r"serving the viewer at (http://\S+)", line)
            if m:
                url = m.group(1)
                break
        assert url, f"no URL printed: {''.join(lines)}{proc.stderr.read() if proc.poll() else ''}"
        yield proc, url
    finally:
        if proc.poll() is None:
            stop_process(proc, signal.SIGINT, timeout=30)


def stop_process(proc, sig, *, timeout) -> None:
    """Send ``sig``; kill the process if it has not ended after ``timeout`` seconds."""
    proc.send_signal(sig)
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@needs_browser
@pytest.mark.parametrize("scene, resolution, integral", [
    # a ball of radius 40 mm, mu 0.2 / cm: a ray near its centre crosses 8 cm, 0.2 * 8 = 1.6
    ("sphere", 48, 1.6),
    pytest.param("default", 96, None, marks=pytest.mark.slow),      # the frog: ~50 s
])
def test_web_viewer_in_chromium(tmp_path, scene, resolution, integral):
    """The page shows the render window streamed from the server; a slider moves the source,
    a click on the radiograph picks a pixel and draws its ray; nothing leaves 127.0.0.1, the
    console logs no error;
    Ctrl-C stops the server cleanly."""
    with web_server(scene, "--port", "0", "--resolution", str(resolution), "--size", "1400",
                    "700") as (proc, url):
        assert urlsplit(url).hostname == "127.0.0.1"
        with browser_page() as page:
            errors = []
            page.on("console", lambda m: m.type == "error" and errors.append(m.text))
            page.on("response", lambda r: r.status >= 400
                    and errors.append(f"{r.status} {r.request.method} {r.url}"))
            page.goto(url)
            result = drive_viewer(page, tmp_path, f"web-{scene}")
            # one set of controls: the page's HTML sliders, not the VTK twins in the picture
            assert page.locator("#xray-viz-controls input[type=range]").count() == 4
            remote = list(page.remote)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-3000:]
    assert "stopped" in out and "Traceback" not in err
    assert not remote, f"the page asked the web for {remote[:5]}"
    # no console error (trame's client POSTed to /paraview/ without the URL's sessionURL: 405)
    assert not errors, errors
    check_driven(result, (resolution, resolution), integral_near=integral)


def test_web_options_are_checked(capsys):
    """--host/--port without --web, --web with --screenshot, a bad port: one line, exit 2."""
    from xray_viz.cli import main

    for argv, words in ((["--port", "8000"], "--host and --port go with --web"),
                        (["--web", "--screenshot", "x.png"], "do not go together"),
                        (["--web", "--port", "70000"], "--port 70000")):
        assert main(["show", "sphere", *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and words in err and err.startswith("xray-viz: error:")


def test_web_viewer_follows_the_viewer_model():
    """The page's state is the Viewer's: a slider sets the model, a change of the model
    (a script, a VTK widget, a click) updates the page's values and picked pixel."""
    import xray_viz
    from xray_viz.viz.web import WebViewer

    web = WebViewer(xray_viz.load_scene("sphere"), resolution=32)
    try:
        web.state["rotation"] = 30.0
        web._on_slider("rotation")
        assert web.viewer.rotation == 30.0
        web.viewer.set_source_distance(800.0)
        assert web.state["source_distance"] == 800.0
        assert "source 800 mm" in web.state["status"]
        profile = web.viewer.pick_pixel(16, 16)
        m = re.search(r"pixel \(16, 16\): integral mu dt = ([\d.]+)", web.state["picked"])
        assert float(m.group(1)) == pytest.approx(profile.line_integral, rel=1e-3)
        # the centre ray through a ball of radius 40 mm, mu 0.2 / cm: at most 0.2 * 8 cm
        assert 0.5 * 1.6 < profile.line_integral <= 1.6 * (1 + 1e-9)
    finally:
        web.close()


# --------------------------------------------------------------------------------------------
# The layout at the page's size: the web view resizes the render window to the browser's


def _text_box(actor, renderer):
    """Display box (x0, x1, y0, y1) of a text actor, in pixels (VTK gives it relative to the
    actor's anchor)."""
    box = [0.0] * 4
    actor.GetBoundingBox(renderer, box)
    x, y = actor.GetPositionCoordinate().GetComputedDisplayValue(renderer)
    return [box[0] + x, box[1] + x, box[2] + y, box[3] + y]


def _legend_box(legend, renderer):
    x0, y0 = legend.GetPositionCoordinate().GetComputedDisplayValue(renderer)
    x1, y1 = legend.GetPosition2Coordinate().GetComputedDisplayValue(renderer)
    return [x0, x1, y0, y1]


def _overlap(a, b) -> bool:
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def _check_layout(viewer, size):
    pl = viewer.plotter
    pl.render()
    r3d, rimg = pl.renderers[0], pl.renderers[1]
    help_box = _text_box(r3d.actors["help"], r3d)
    legend = _legend_box(r3d.legend, r3d)
    labels = [_text_box(r3d.actors[f"check-{g}"], r3d) for g in ("rays", "grid", "hits",
                                                                  "vectors")]
    title = _text_box(rimg.actors["radiograph-title"], rimg)
    w, h = size
    assert not _overlap(help_box, legend), (help_box, legend)
    assert 0 <= help_box[0] and help_box[1] <= w / 2 and help_box[3] <= h
    assert w / 2 <= title[0] and title[1] <= w and title[3] <= h
    for a, b in zip(labels, labels[1:]):
        assert not _overlap(a, b), (a, b)
    assert all(not _overlap(lab, legend) for lab in labels)


@pytest.mark.parametrize("scene, size", [
    ("sphere", (800, 400)),
    # the frog's legend has eleven entries; 1034 px: JupyterLab's output width
    *(pytest.param("frog", s, marks=pytest.mark.slow) for s in [(800, 400), (1034, 700),
                                                                (1400, 700)]),
])
def test_viewer_texts_do_not_overlap_at_any_window_size(scene, size):
    """The key help, the legend, the check boxes' labels and the
    radiograph's title stay apart and inside their panes, in a window made at that size and
    in one resized to it (as the web page's view does); a resize to the reference size brings
    the font sizes back."""
    import xray_viz
    from xray_viz.viz.viewer import Viewer

    viewer = Viewer(xray_viz.load_scene(scene), resolution=32, window_size=size,
                    off_screen=True)
    try:
        _check_layout(viewer, size)
        base = viewer.view._fixed_texts["help"][1]
        viewer.plotter.render_window.SetSize(1200, 600)
        assert viewer.plotter.renderers[0].actors["help"].GetTextProperty().GetFontSize() \
            == base
        _check_layout(viewer, (1200, 600))
        viewer.plotter.render_window.SetSize(*size)
        _check_layout(viewer, size)
    finally:
        viewer.close()


def test_show_outside_a_notebook_without_a_display(monkeypatch):
    """``xray_viz.show`` in a script on a machine without a display: one line that names the
    notebook and ``--web`` instead of a window that never opens."""
    import xray_viz
    from xray_viz.errors import XrayVizError

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    with pytest.raises(XrayVizError, match=r"no display .*notebook.*--web") as exc:
        xray_viz.show("sphere")
    assert "\n" not in str(exc.value)
    assert xray_viz.show.__module__ == "xray_viz.viz.notebook"


def test_server_loop_drops_messages_to_closing_connections_only(caplog):
    """A message to a page whose connection is closing fails in a task nobody awaits (Ctrl-C
    while a frame is on its way): the server's loop drops that one quietly, and still reports
    any other error of a task as asyncio does."""
    import asyncio
    import gc

    from xray_viz.viz import web

    async def fails(exc):
        raise exc

    async def main():
        web._own_loop_drops_closing_connections()
        for exc in (ConnectionResetError("Cannot write to closing transport"),
                    ValueError("a real bug")):
            task = asyncio.get_running_loop().create_task(fails(exc))
            await asyncio.sleep(0.01)
            assert task.done()
            del task
            gc.collect()

    with caplog.at_level("ERROR", logger="asyncio"):
        asyncio.run(main())
    logged = [r.getMessage() + str(r.exc_info) for r in caplog.records if r.name == "asyncio"]
    assert len(logged) == 1 and "a real bug" in logged[0], logged


# --------------------------------------------------------------------------------------------
# The chest: the radiograph on the PNG's log scale; tabs closed while the server sends


CHEST = ("chest", "--port", "0", "--resolution", "128", "--size", "1400", "700")


def _stop(proc) -> tuple[str, str]:
    proc.send_signal(signal.SIGINT)
    return proc.communicate(timeout=60)


@needs_browser
def test_web_viewer_shows_the_chest_on_the_log_scale(tmp_path):
    """The chest's radiograph in the page's picture (rendered by the server): the implant
    brighter than the spine beside it, the heart than the lungs, as in the desktop viewer
    (``test_viz_log_window``: the PNG's log scale). Where each anatomy's pixels are drawn
    comes from an off-screen web viewer of the same scene at the view's size, whose picture
    the page's must match."""
    import xray_viz
    from tests.viz.test_viz_log_window import chest_regions, region_greys
    from xray_viz.viz.web import WebViewer

    with web_server(*CHEST) as (proc, url):
        with browser_page() as page:
            page.goto(url)
            view = page.locator("#xray-viz-view")
            view.locator("img").first.wait_for(timeout=60_000)
            h, w = save_shot(view, tmp_path, "web-chest").shape[:2]
            local = WebViewer(xray_viz.load_scene("chest"), resolution=128, height=h,
                              window_size=(w, h)).viewer
            try:
                local.plotter.render()
                want = np.asarray(local.plotter.screenshot(None, return_img=True),
                                  dtype=float)[..., :3]
                regions = chest_regions(local.radiograph)

                def same(shot):
                    return shot.shape == want.shape and np.abs(shot - want).mean() < 6

                shot = wait_for_shot(view, tmp_path, "web-chest", same)
                grey = region_greys(local.view, shot, regions)
            finally:
                local.close()
        _, err = _stop(proc)
    assert same(shot), np.abs(shot - want).mean() if shot.shape == want.shape else shot.shape
    # (the stream's JPEG softens the thin rods: ~25 levels above the spine, ~35 off-screen;
    # a linear window drew both at 254-255)
    assert grey["implant"] > grey["spine"] + 15, grey
    assert grey["heart"] > grey["lungs"] + 50, grey
    assert "Traceback" not in err, err[-3000:]


#: Tabs opened and closed at once after a click or a slider's move, on one server.
CLOSES = 12


@needs_browser
def test_closing_tabs_while_the_server_sends_writes_no_traceback():
    """A tab closed while the server still sends it a reply or a picture (the chest: large
    pictures, slow renders; about one close in four hit it) made wslink and aiohttp write
    tracebacks to stderr ("Exception raised", "Error handling request"): every close here
    follows a click on the radiograph or a slider's move at a varying delay, and stderr stays
    clean; the server still stops with 0 on Ctrl-C."""
    with web_server(*CHEST) as (proc, url):
        with browser_page() as page:
            for k in range(CLOSES):
                tab = page.context.new_page()
                tab.goto(url)
                view = tab.locator("#xray-viz-view")
                view.locator("img").first.wait_for(timeout=60_000)
                if k % 2:
                    box = view.bounding_box()
                    tab.mouse.click(box["x"] + 0.712 * box["width"],
                                    box["y"] + 0.39 * box["height"])
                else:
                    tab.locator("#slider-source_distance").focus()
                    tab.keyboard.press("PageDown" if k % 4 else "PageUp")
                time.sleep(0.05 * (k % 5))
                tab.close()
        out, err = _stop(proc)
    assert proc.returncode == 0, err[-3000:]
    assert "stopped" in out
    for words in ("Traceback", "Exception raised", "Error handling request"):
        assert words not in err, err[-3000:]


def test_a_closing_websocket_drops_its_messages_and_the_others_get_theirs():
    """What the server's websockets do once :func:`start` has bound it: a send to a closing
    connection (aiohttp raises ConnectionResetError) is dropped, a send to an open one goes
    through, and the handler's own ``onConnect`` still runs."""
    import asyncio
    import types

    from xray_viz.viz import web

    class Socket:
        def __init__(self, closing):
            self.closing, self.got = closing, []

        async def send_bytes(self, data):
            if self.closing:
                raise ConnectionResetError("Cannot write to closing transport")
            self.got.append(data)

    connected = []

    class Handler:
        def __init__(self):
            self.connections = {"gone": Socket(True), "open": Socket(False)}

        async def onConnect(self, request, client_id):
            connected.append(client_id)

    handler = Handler()
    web._quiet_closing_websockets(types.SimpleNamespace(_ws_handlers=[handler]))

    async def main():
        for client in ("gone", "open"):
            await handler.onConnect(None, client)
        for ws in handler.connections.values():       # as wslink's send loop does
            await ws.send_bytes(b"picture")

    asyncio.run(main())
    assert connected == ["gone", "open"]
    assert handler.connections["open"].got == [b"picture"]
    assert handler.connections["gone"].got == []
    with pytest.raises(ConnectionResetError):            # unwrapped: what wslink saw
        asyncio.run(Socket(True).send_bytes(b"picture"))
