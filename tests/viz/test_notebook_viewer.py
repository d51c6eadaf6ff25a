"""``xray_viz.show(scene)`` in JupyterLab: the viewer in a notebook's output cell, in Chromium.

The test starts a Jupyter server (JupyterLab) on 127.0.0.1 with a token and every Jupyter and
IPython folder in a temporary directory (one kernel spec, ``xray_viz``: this interpreter), opens a
notebook that calls ``xray_viz.show(...)`` in headless Chromium, runs its cell in the server's
kernel (Shift+Enter, as a student does), and drives the viewer that appears in the output: a
slider, a click on the radiograph, screenshots (``test_web_viewer``'s helpers and checks).
Requests for anything but 127.0.0.1 are recorded and refused.
"""

from __future__ import annotations

import contextlib
import io
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from urllib.parse import urlsplit

import nbformat
import numpy as np
import pytest
from PIL import Image

from tests.viz.test_web_viewer import (browser_page, check_driven, drive_viewer, needs_browser,
                             non_background, save_shot, stop_process, view_region)

TOKEN = "xray-viz-test-token"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _jupyter_env(tmp_path) -> dict:
    """Jupyter's and IPython's folders in tmp_path; one kernel spec, this interpreter's."""
    from ipykernel.kernelspec import write_kernel_spec

    data = tmp_path / "jupyter-data"
    write_kernel_spec(data / "kernels" / "xray_viz", overrides={"display_name": "xray_viz"})
    env = {k: v for k, v in os.environ.items() if not k.startswith(("JUPYTER", "IPYTHON"))}
    env.pop("DISPLAY", None)
    env.update(JUPYTER_PLATFORM_DIRS="1", JUPYTER_PATH=str(data),
               JUPYTER_DATA_DIR=str(tmp_path / "jupyter-user-data"),
               JUPYTER_CONFIG_DIR=str(tmp_path / "jupyter-config"),
               JUPYTER_RUNTIME_DIR=str(tmp_path / "jupyter-runtime"),
               JUPYTERLAB_SETTINGS_DIR=str(tmp_path / "lab-settings"),
               JUPYTERLAB_WORKSPACES_DIR=str(tmp_path / "lab-workspaces"),
               IPYTHONDIR=str(tmp_path / "ipython"), PYTHONUNBUFFERED="1",
               MPLBACKEND="Agg")
    return env


@contextlib.contextmanager
def jupyter_lab(root, env, timeout=180, base_url="/"):
    """JupyterLab on 127.0.0.1 (a free port, a token) under ``base_url``; yields its URL
    (``http://127.0.0.1:PORT`` + ``base_url`` without its last ``/``)."""
    port = _free_port()
    log = open(root.parent / "jupyter.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", "--ServerApp.ip=127.0.0.1",
         f"--ServerApp.port={port}", "--ServerApp.port_retries=0",
         f"--ServerApp.base_url={base_url}",
         f"--IdentityProvider.token={TOKEN}", f"--ServerApp.root_dir={root}",
         "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
         # nothing from the web: no news, no update check, no extension catalogue
         "--LabApp.news_url=None", "--LabApp.extension_manager=readonly",
         "--ServerApp.terminals_enabled=False",
         *(["--allow-root"] if hasattr(os, "geteuid") and os.geteuid() == 0 else [])],
        stdout=log, stderr=subprocess.STDOUT, env=env, cwd=root)
    base = f"http://127.0.0.1:{port}{base_url.rstrip('/')}"
    try:
        end = time.monotonic() + timeout
        while True:
            try:
                with urllib.request.urlopen(f"{base}/api/status?token={TOKEN}", timeout=5):
                    break
            except OSError:
                if proc.poll() is not None or time.monotonic() > end:
                    log.flush()
                    raise AssertionError("Jupyter did not start:\n"
                                         + (root.parent / "jupyter.log").read_text()[-3000:])
                time.sleep(0.5)
        yield base
    finally:
        stop_process(proc, signal.SIGTERM, timeout=60)
        log.close()


def _notebook(path, source):
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "xray_viz", "display_name": "xray_viz",
                                 "language": "python"}
    nb.cells = [nbformat.v4.new_code_cell(source)]
    nbformat.write(nb, path)


@pytest.mark.slow   # JupyterLab's start and page, a kernel, a viewer: ~1-2 min on 2 cores
@needs_browser
def test_show_in_jupyterlab_in_chromium(tmp_path):
    """A notebook cell ``xray_viz.show(...)`` puts the viewer in its output; in Chromium its
    slider moves the source and a click on its radiograph picks a pixel and draws the ray."""
    root = tmp_path / "notebooks"
    root.mkdir()
    _notebook(root / "viewer.ipynb",
              'import xray_viz\nviewer = xray_viz.show("sphere", resolution=48, height=700)')
    env = _jupyter_env(tmp_path)
    with jupyter_lab(root, env) as base, browser_page(viewport=(1500, 1100)) as page:
        page.goto(f"{base}/lab/tree/viewer.ipynb?token={TOKEN}")
        editor = page.locator(".jp-Notebook .jp-Cell .cm-content").first
        editor.wait_for(timeout=120_000)
        # the notebook's kernel is started and connected (JupyterLab's status bar)
        page.get_by_text("xray_viz | Idle").wait_for(timeout=120_000)
        editor.click()
        page.keyboard.press("Shift+Enter")                  # run the cell, as a student does
        frame_el = page.locator("iframe#xray-viz-frame")
        frame_el.wait_for(timeout=180_000)
        src = frame_el.get_attribute("src")
        frame = page.frame_locator("iframe#xray-viz-frame")
        frame_el.scroll_into_view_if_needed()
        result = drive_viewer(page, tmp_path, "notebook", frame=frame)
        save_shot(page, tmp_path, "notebook-4-lab")
        remote = list(page.remote)
    # jupyter-server-proxy is installed: the page goes through the notebook's server
    assert src.startswith("/proxy/") and urlsplit(src).hostname is None, src
    assert not remote, f"the page asked the web for {remote[:5]}"
    check_driven(result, (48, 48), integral_near=1.6)


# --------------------------------------------------------------------------------------------
# Remote notebooks: the viewer through jupyter-server-proxy, under a path prefix

def _run_in_kernel(base, code, timeout=240) -> list[dict]:
    """Start a kernel through the server's REST API, run ``code`` in it; its outputs
    (``display_data`` / ``execute_result`` / ``error`` contents). The kernel keeps running."""
    import json
    import uuid

    import websocket

    req = urllib.request.Request(f"{base}/api/kernels?token={TOKEN}", method="POST",
                                 data=json.dumps({"name": "xray_viz"}).encode(),
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=60) as r:
        kernel = json.load(r)["id"]
    ws = websocket.create_connection(
        f"ws{base[4:]}/api/kernels/{kernel}/channels?token={TOKEN}", timeout=timeout)
    msg_id = uuid.uuid4().hex
    ws.send(json.dumps({
        "header": {"msg_id": msg_id, "username": "test", "session": uuid.uuid4().hex,
                   "msg_type": "execute_request", "version": "5.3"},
        "parent_header": {}, "metadata": {}, "channel": "shell", "buffers": [],
        "content": {"code": code, "silent": False, "store_history": True,
                    "user_expressions": {}, "allow_stdin": False, "stop_on_error": True}}))
    outputs = []
    end = time.monotonic() + timeout
    try:
        while time.monotonic() < end:
            msg = json.loads(ws.recv())
            if msg.get("parent_header", {}).get("msg_id") != msg_id:
                continue
            kind = msg["msg_type"]
            if kind in ("display_data", "execute_result", "error", "stream"):
                outputs.append({"type": kind, **msg["content"]})
            if kind == "status" and msg["content"]["execution_state"] == "idle":
                return outputs
    finally:
        ws.close()
    raise AssertionError(f"the cell did not finish in {timeout} s: {outputs}")


def _output_html(outputs) -> str:
    errors = [o for o in outputs if o["type"] == "error" or o.get("name") == "stderr"]
    assert not [o for o in errors if o["type"] == "error"], errors
    htmls = [o["data"]["text/html"] for o in outputs if "text/html" in o.get("data", {})]
    assert len(htmls) == 1, outputs
    return htmls[0]


def _put_output(page, html_text) -> None:
    """Put an output cell's HTML over the page and run its script, as JupyterLab does."""
    import re as _re

    body, script = html_text.split("<script>", 1)
    page.evaluate("""html => {
        const cell = document.createElement("div");
        cell.style.cssText = "position: fixed; inset: 0; z-index: 100000; background: white";
        cell.innerHTML = html;
        document.body.appendChild(cell);
    }""", body)
    page.add_script_tag(content=_re.sub(r"</script>\s*$", "", script))


def _still_picture(page) -> np.ndarray:
    import base64
    import io

    src = page.locator("img.xray-viz-static").get_attribute("src")
    assert src.startswith("data:image/png;base64,")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1])))
                      .convert("RGB"), dtype=float)


@pytest.mark.slow   # JupyterLab's start and page, a kernel, a viewer: ~65 s on 2 busy cores
@needs_browser
def test_show_through_jupyter_server_proxy_under_a_prefix(tmp_path):
    """JupyterLab under ``/prefix/`` with jupyter-server-proxy: ``xray_viz.show`` in its kernel
    finds the proxy by itself; its output, in Chromium on the notebook server's site, swaps its
    still picture for the page at ``/prefix/proxy/PORT/`` (the websocket through the proxy
    too): the 3D view has pixels, there is one set of controls (no VTK slider repeats an HTML
    one), the slider and a click work, and the console logs no error."""
    root = tmp_path / "notebooks"
    root.mkdir()
    env = _jupyter_env(tmp_path)
    env.pop("XRAY_VIZ_PROXY", None)
    with jupyter_lab(root, env, base_url="/prefix/") as base:
        outputs = _run_in_kernel(base, 'import xray_viz\n'
                                       'nv = xray_viz.show("sphere", resolution=48, height=700)\n'
                                       'print(nv.url)')
        html_text = _output_html(outputs)
        url = "".join(o["text"] for o in outputs if o.get("name") == "stdout").strip()
        assert url.startswith("/prefix/proxy/") and "sessionURL=" in url, url
        with browser_page(viewport=(1500, 1100)) as page:
            console = []
            page.on("console", lambda m: console.append((m.type, m.text)))
            page.on("response", lambda r: r.status >= 400
                    and console.append(("http", f"{r.status} {r.request.method} {r.url}")))
            # JupyterLab's page (the token: Jupyter's login cookie, for the proxy too), the
            # output cell over it
            page.goto(f"{base}/lab?token={TOKEN}")
            page.locator("#jp-main-dock-panel").wait_for(timeout=120_000)
            _put_output(page, html_text)
            still = _still_picture(page)
            frame_el = page.locator("iframe#xray-viz-frame")
            frame_el.wait_for(timeout=60_000)
            src = frame_el.get_attribute("src")
            frame = page.frame_locator("iframe#xray-viz-frame")
            result = drive_viewer(page, tmp_path, "proxied", frame=frame)
            controls = frame.locator("#xray-viz-controls input[type=range]").count()
            save_shot(page, tmp_path, "proxied-4-page")
            remote = list(page.remote)
    assert src == url
    assert not remote, f"the page asked the web for {remote[:5]}"
    errors = [c for c in console if c[0] in ("error", "http")]
    assert not errors, errors
    # the still picture is the viewer's window: the 3D drawing and the radiograph
    assert non_background(view_region(still, "3d")) > 0.02
    assert non_background(view_region(still, "radiograph")) > 0.1
    # one set of controls: the HTML row's sliders; the VTK ones it repeats are off
    assert controls == 4                          # distance, rotation, energy, resolution
    check_driven(result, (48, 48), integral_near=1.6)


def test_one_set_of_controls_and_a_still_picture():
    """The VTK sliders that the page's HTML row repeats are off (window and level, which
    only VTK has, stay); ``backend="static"``'s output is the window's still picture, with
    no live page to try; a proxied viewer's address is relative to the notebook's site."""
    import xray_viz
    from xray_viz.viz.notebook import NotebookViewer, proxy_prefix
    from xray_viz.viz.web import WebViewer

    web = WebViewer(xray_viz.load_scene("sphere"), resolution=32, height=400)
    try:
        on = {k: bool(w.GetEnabled()) for k, w in web.viewer.sliders.items()}
        assert on == {"source_distance": False, "rotation": False, "energy": False,
                      "resolution": False, "window": True, "level": True}
        still = NotebookViewer(web, host="127.0.0.1", live=False)
        assert still.candidates() == [] and "<script>" not in still._repr_html_()
        shot = np.asarray(Image.open(io.BytesIO(still._repr_png_())).convert("RGB"),
                          dtype=float)
        assert shot.shape == (400, 1400, 3)
        assert non_background(view_region(shot, "3d")) > 0.02
        assert non_background(view_region(shot, "radiograph")) > 0.1
        web.server._running_port = 4321            # as once started (trame keeps it there)
        proxied = NotebookViewer(web, host="127.0.0.1", prefix=proxy_prefix("/user/me/proxy"))
        assert proxied.url.startswith("/user/me/proxy/4321/index.html?secret=")
        assert "sessionURL=ws%3A%2F%2FUSE_HOST%2Fuser%2Fme%2Fproxy%2F4321%2Fws" in proxied.url
        assert proxied.candidates()[1].startswith("http://127.0.0.1:4321/")
    finally:
        web.close()


def test_proxy_prefix_from_the_environment(monkeypatch):
    """``XRAY_VIZ_PROXY``: 0 (none), 1 (this server's base_url + proxy/), a prefix;
    JupyterHub's service prefix is detected."""
    from xray_viz.viz.notebook import proxy_prefix

    monkeypatch.delenv("JUPYTERHUB_SERVICE_PREFIX", raising=False)
    monkeypatch.setenv("XRAY_VIZ_PROXY", "0")
    assert proxy_prefix() is None
    monkeypatch.setenv("XRAY_VIZ_PROXY", "/hub/user/a/proxy/absolute")
    assert proxy_prefix() == "/hub/user/a/proxy/absolute/"
    monkeypatch.setenv("XRAY_VIZ_PROXY", "1")
    monkeypatch.setenv("JUPYTERHUB_SERVICE_PREFIX", "/user/a/")
    assert proxy_prefix() == "/user/a/proxy/"
    monkeypatch.delenv("XRAY_VIZ_PROXY")
    assert proxy_prefix() == "/user/a/proxy/"           # detected: jupyter-server-proxy
    assert proxy_prefix(False) is None


@needs_browser
def test_still_picture_stays_when_no_server_answers(tmp_path):
    """The output cell of a viewer whose server cannot be reached (neither through a proxy nor
    directly: a closed port) keeps its still picture, says so, and shows no empty frame."""
    import xray_viz
    from xray_viz.viz.notebook import NotebookViewer
    from xray_viz.viz.web import WebViewer

    web = WebViewer(xray_viz.load_scene("sphere"), resolution=32, height=400)
    try:
        web.server._running_port = _free_port()          # nobody listens there
        html_text = NotebookViewer(web, host="127.0.0.1", prefix="/nowhere/proxy/")._repr_html_()
    finally:
        web.close()
    with browser_page() as page:
        page.set_content("<html><body></body></html>")
        _put_output(page, html_text)
        note = page.locator(".xray-viz-note")
        note.wait_for(state="visible", timeout=30_000)
        text = note.inner_text()
        frames = page.locator("iframe").count()
        still = _still_picture(page)
        shot = save_shot(page.locator("img.xray-viz-static"), tmp_path, "still-fallback")
    assert "cannot be reached" in text and frames == 0
    assert non_background(view_region(still, "3d")) > 0.02
    assert non_background(view_region(shot, "radiograph")) > 0.1     # drawn on the page
