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
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from urllib.parse import urlsplit

import nbformat
import pytest

from test_web_viewer import (browser_page, check_driven, drive_viewer, needs_browser, save_shot,
                             stop_process)

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
def jupyter_lab(root, env, timeout=180):
    """JupyterLab on 127.0.0.1 (a free port, a token); yields its base URL."""
    port = _free_port()
    log = open(root.parent / "jupyter.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "jupyterlab", "--no-browser", "--ServerApp.ip=127.0.0.1",
         f"--ServerApp.port={port}", "--ServerApp.port_retries=0",
         f"--IdentityProvider.token={TOKEN}", f"--ServerApp.root_dir={root}",
         "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
         # nothing from the web: no news, no update check, no extension catalogue
         "--LabApp.news_url=None", "--LabApp.extension_manager=readonly",
         "--ServerApp.terminals_enabled=False",
         *(["--allow-root"] if hasattr(os, "geteuid") and os.geteuid() == 0 else [])],
        stdout=log, stderr=subprocess.STDOUT, env=env, cwd=root)
    base = f"http://127.0.0.1:{port}"
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
    assert urlsplit(src).hostname == "127.0.0.1"
    assert not remote, f"the page asked the web for {remote[:5]}"
    check_driven(result, (48, 48), integral_near=1.6)
