"""The documentation site builds, shows every walkthrough with its figures, loads nothing from
the web, and its walkthrough notebooks run in a kernel.

The site is built once per session by the command ``make docs`` runs (``sphinx-build -W
--keep-going``: any warning fails the build) into a temporary folder, so that every page is
read and written and every warning is seen. sphinx-gallery keeps its results in
``docs/walkthroughs/`` (gitignored): a walkthrough that did not change since its last successful
run is not run again, and ``docs/conf.py`` re-runs all of them when the package, its phantoms or
the configuration changed.

The browser tests load the built pages in headless Chromium (Debian's, installed by
``.ci/system-deps``): the index and a walkthrough page from disk, the interactive 3D view from a
server on 127.0.0.1 (vtk.js fetches its scene file, which browsers refuse over ``file://``).
"""

from __future__ import annotations

import functools
import http.server
import importlib
import importlib.util
import inspect
import json
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import zipfile
from dataclasses import dataclass
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import parse_qs, unquote, urlsplit

import numpy as np
import pytest
from PIL import Image

from tests.docs.test_walkthroughs import EXPECTED_PNGS
from xray_viz.walkthroughs import list_walkthroughs
from helpers import REPO

DOCS = REPO / "docs"

#: Modules the API reference must cover (issue 17), each with a page per public object.
API_MODULES = [
    "xray_viz", "xray_viz.scene", "xray_viz.scene_file", "xray_viz.geometry", "xray_viz.tracing",
    "xray_viz.tracing.intersect", "xray_viz.tracing.hits", "xray_viz.tracing.candidates",
    "xray_viz.tracing.fast", "xray_viz.tracing.engines", "xray_viz.tracing.reference",
    "xray_viz.attenuation", "xray_viz.physics",
    "xray_viz.physics.imaging", "xray_viz.physics.materials", "xray_viz.physics.spectra",
    "xray_viz.physics.detector", "xray_viz.physics.dosimetry", "xray_viz.physics.heel",
    "xray_viz.bodies",
    "xray_viz.output", "xray_viz.meshes", "xray_viz.meshes.io", "xray_viz.meshes.repair",
    "xray_viz.meshes.decimate", "xray_viz.phantoms", "xray_viz.render", "xray_viz.errors",
    "xray_viz.walkthroughs", "xray_viz.viz",
]

#: Walkthroughs executed as notebooks: a PyVista one with slider frames, and one with
#: Matplotlib, tracing and a 3D scene.
NOTEBOOKS = [1, 7]


# --------------------------------------------------------------------------------------------
# The build


@dataclass
class Site:
    returncode: int
    stdout: str
    stderr: str
    html: Path

    def page(self, path: str) -> Path:
        return self.html / path


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Site:
    missing = [m for m in ("sphinx", "sphinx_gallery", "numpydoc", "myst_parser",
                           "pydata_sphinx_theme", "sphinx_design")
               if importlib.util.find_spec(m) is None]
    if missing:
        pytest.fail(f"the docs extra is not installed ({', '.join(missing)} missing): "
                    "pip install -e '.[docs]' (make setup installs it)")
    out = tmp_path_factory.mktemp("docs")
    cmd = [sys.executable, "-m", "sphinx", "-b", "html", "-W", "--keep-going", "-q",
           "-d", str(out / "doctrees"), str(DOCS), str(out / "html")]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=1500)
    return Site(proc.returncode, proc.stdout, proc.stderr, out / "html")


def test_docs_build_with_warnings_as_errors(site):
    assert site.returncode == 0, f"sphinx-build failed:\n{site.stderr[-6000:]}"
    assert "WARNING" not in site.stderr and "ERROR" not in site.stderr, site.stderr[-6000:]
    assert site.page("index.html").is_file()


# --------------------------------------------------------------------------------------------
# Reading the built pages


class _Tags(HTMLParser):
    """Every tag of a page with its attributes, and its text."""

    def __init__(self):
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict]] = []
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))

    def handle_data(self, data):
        self.text.append(data)


def _parse(html: str) -> _Tags:
    parser = _Tags()
    parser.feed(html)
    return parser


def _plain(text: str) -> str:
    """Text without Sphinx's typographic quotes and without reST's double backquotes."""
    return (text.replace("\u2019", "'").replace("\u2018", "'").replace("\u201c", '"')
            .replace("\u201d", '"').replace("``", ""))


def _local(page: Path, url: str) -> Path:
    """The file a relative URL of ``page`` points at."""
    return (page.parent / unquote(urlsplit(url).path)).resolve()


def _check_png(path: Path, *, min_size=300, min_std=8.0):
    assert path.is_file(), f"missing image {path}"
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", f"{path.name} is not a PNG"
    grey = np.asarray(Image.open(path).convert("L"), dtype=float)
    assert min(grey.shape) >= min_size, f"{path.name} is only {grey.shape}"
    assert grey.std() > min_std, f"{path.name} looks blank (std {grey.std():.1f})"


def _walkthrough_source(name: str) -> str:
    return (REPO / "apps" / "walkthroughs" / f"{name}.py").read_text(encoding="utf-8")


def _figure_images(tags, name):
    """The walkthrough's figures on its page, in order (sphinx-gallery's numbered PNGs)."""
    pattern = re.compile(rf"sphx_glr_{name}_(\d\d\d)\.png$")
    srcs = [a["src"] for t, a in tags.tags if t == "img" and pattern.search(a.get("src", ""))]
    return list(dict.fromkeys(srcs))


def _viewer_frames(tags):
    return [a["src"] for t, a in tags.tags if t == "iframe" and "static_viewer.html" in a.get("src", "")]


@pytest.mark.parametrize("number, name", [(n, name) for n, name, _ in list_walkthroughs()])
def test_every_walkthrough_is_a_page_with_its_figures(site, number, name):
    """Each walkthrough ran in the build: its page shows as many figures as the off-screen run
    writes PNGs, and one interactive vtk.js view per 3D scene (``show_or_save``)."""
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page(f"walkthroughs/{name}.html")
    html = page.read_text(encoding="utf-8")
    tags = _parse(html)
    images = _figure_images(tags, name)
    assert len(images) == len(EXPECTED_PNGS[number]), (name, images)
    for src in images:
        _check_png(_local(page, src))
    scenes = len(re.findall(r"\bshow_or_save\(", _walkthrough_source(name)))
    frames = _viewer_frames(tags)
    assert len(frames) == scenes, (name, frames)
    for src in frames:
        viewer = _local(page, src)
        assert viewer.is_file()
        scene_file = (viewer.parent / parse_qs(urlsplit(src).query)["fileURL"][0]).resolve()
        with zipfile.ZipFile(scene_file) as archive:
            index = json.loads(archive.read("index.json"))
        assert index.get("scene"), f"{scene_file.name} holds no scene"
    # what the walkthrough printed is on the page, and nothing went wrong while it ran
    text = "".join(tags.text)
    assert "Traceback" not in text and "Task exception" not in text, name
    assert re.search(r"Total running time of the script", text)


def test_gallery_index_lists_every_walkthrough(site):
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page("walkthroughs/index.html")
    tags = _parse(page.read_text(encoding="utf-8"))
    links = {a.get("href", "") for t, a in tags.tags if t == "a"}
    thumbs = [a["src"] for t, a in tags.tags if t == "img" and "_thumb" in a.get("src", "")]
    for _, name, _ in list_walkthroughs():
        assert f"{name}.html" in links or f"{name}.html#" in links, name
    assert len(thumbs) == len(list_walkthroughs())
    for src in thumbs:
        _check_png(_local(page, src), min_size=100)


def test_examples_gallery_beside_the_walkthroughs(site):
    """The task examples (apps/examples) are a gallery of their own: every script is listed on
    its index and ran in the build; "Find the implant" shows its three figures (overlay before,
    after, the loss curve) and found the stem (its printed mTRE below 0.1 mm)."""
    assert site.returncode == 0, site.stderr[-3000:]
    scripts = sorted(p.stem for p in (REPO / "apps" / "examples").glob("[a-z]*.py"))
    assert "find_the_implant" in scripts
    index = _parse(site.page("examples/index.html").read_text(encoding="utf-8"))
    links = {a.get("href", "") for t, a in index.tags if t == "a"}
    for name in scripts:
        assert f"{name}.html" in links, name
    page = site.page("examples/find_the_implant.html")
    tags = _parse(page.read_text(encoding="utf-8"))
    images = _figure_images(tags, "find_the_implant")
    assert len(images) == 3, images
    for src in images:
        _check_png(_local(page, src))
    text = "".join(tags.text)
    assert "Traceback" not in text
    assert float(re.search(r"mTRE fitted: ([\d.]+) mm", text).group(1)) < 0.1


TASK_EXAMPLES = sorted(p.stem for p in (REPO / "apps" / "examples").glob("plot_*.py"))

#: Issue 43's tasks (the gallery's examples, whose pages the tests below check): your own mesh,
#: an implant in a CT, a CT scan and its reconstruction, a DRR dataset with Dask, DICOM and
#: NIfTI out and back, and the open issues' dose, scatter and registration.
ISSUE_43_TASKS = {"plot_your_own_mesh", "plot_implant_in_ct", "plot_ct_reconstruction",
                  "plot_drr_dataset_dask", "plot_dicom_nifti_round_trip", "plot_dose",
                  "plot_scatter_and_grid", "find_the_implant"}


def test_the_tasks_gallery_has_an_example_per_task():
    """Each task of issue 43 is a script of the Tasks gallery (apps/examples), titled in its
    docstring (the gallery's heading) and ending with what to try next."""
    scripts = {p.stem: p for p in (REPO / "apps" / "examples").glob("[a-z]*.py")}
    assert ISSUE_43_TASKS <= set(scripts), sorted(ISSUE_43_TASKS - set(scripts))
    for name in ISSUE_43_TASKS:
        text = scripts[name].read_text(encoding="utf-8")
        title = text.split('"""')[1].strip().splitlines()
        assert len(title) >= 2 and set(title[1]) <= {"=", "-"}, name
        assert name == "find_the_implant" or "What to try next" in text, name


def test_tasks_gallery_is_a_second_section_beside_the_walkthroughs(site):
    """Issue 43: the task examples are their own gallery (docs/examples), each run by the build
    with its figures on its page; the walkthroughs' gallery still lists only the twelve."""
    assert site.returncode == 0, site.stderr[-3000:]
    assert len(TASK_EXAMPLES) >= 3
    index = site.page("examples/index.html")
    tags = _parse(index.read_text(encoding="utf-8"))
    links = {a.get("href", "").split("#")[0] for t, a in tags.tags if t == "a"}
    thumbs = [a["src"] for t, a in tags.tags if t == "img" and "_thumb" in a.get("src", "")]
    every = sorted(p.stem for p in (REPO / "apps" / "examples").glob("[a-z]*.py"))
    assert {f"{name}.html" for name in every} <= links and len(thumbs) == len(every)
    for name in TASK_EXAMPLES:
        page = site.page(f"examples/{name}.html")
        tags = _parse(page.read_text(encoding="utf-8"))
        images = _figure_images(tags, name)
        assert images, name
        for src in images:
            _check_png(_local(page, src))
        text = "".join(tags.text)
        assert "Traceback" not in text and "What to try next" in text, name
    walk = _parse(site.page("walkthroughs/index.html").read_text(encoding="utf-8"))
    assert not any("plot_" in a.get("href", "") for t, a in walk.tags if t == "a")
    assert len(list_walkthroughs()) == 12


def _example_text(site, name):
    page = site.page(f"examples/{name}.html")
    tags = _parse(page.read_text(encoding="utf-8"))
    return page, tags, _plain("".join(tags.text))


def test_drr_dataset_example_ran_on_dask_workers(site):
    """Issue 43, "A DRR dataset with Dask": 36 DRRs rendered by two worker processes into a
    Zarr store, read back; the workers' projection 5 equals this process's, bit for bit; the
    montage is on the page."""
    assert site.returncode == 0, site.stderr[-3000:]
    page, tags, text = _example_text(site, "plot_drr_dataset_dask")
    assert re.search(r"scheduler at tcp://127\.0\.0\.1:\d+, 2 workers", text), text[:2000]
    assert "36 projections of 48 x 96, float32" in text
    assert "projection 5 rendered here equals the worker's: True" in text
    (image,) = _figure_images(tags, "plot_drr_dataset_dask")
    _check_png(_local(page, image))


def test_dose_example_prints_the_dose_table_with_its_errors(site):
    """Issue 43, "Dose": the limb phantom's six bodies each with a dose and its standard error
    (the energy balance closed), cortical bone absorbing more per gram than the muscle around
    it (its calcium's photoelectric absorption), and the chart and the four images shown."""
    from xray_viz import load_scene

    assert site.returncode == 0, site.stderr[-3000:]
    page, tags, text = _example_text(site, "plot_dose")
    rows = {m[0]: [float(x) for x in m[1:]] for m in re.findall(
        r"^ *(\w+) +([\d.]+) +([\d.]+) +([\d.]+) +([\d.]+) +[\d.]+%$", text, flags=re.M)}
    assert sorted(rows) == sorted(b.name for b in load_scene("limb").bodies), text[-3000:]
    for name, (energy, energy_error, dose, dose_error) in rows.items():
        assert 0 < energy_error < 0.1 * energy and 0 < dose_error < 0.1 * dose, name
        assert dose_error / dose == pytest.approx(energy_error / energy, rel=0.05), name
    for bone in ("radius_bone", "ulna_bone"):
        assert rows[bone][2] - 3 * rows[bone][3] > rows["muscle"][2] + 3 * rows["muscle"][3]
    balance = float(re.search(r"emitted - all the others = ([-+.\de]+) eV", text).group(1))
    assert abs(balance) < 1e-6
    images = _figure_images(tags, "plot_dose")
    assert len(images) == 2, images
    for src in images:
        _check_png(_local(page, src))


def test_walkthrough_notebooks_and_scripts_are_offered(site):
    import nbformat

    assert site.returncode == 0, site.stderr[-3000:]
    for _, name, title in list_walkthroughs():
        page = site.page(f"walkthroughs/{name}.html")
        hrefs = [a.get("href", "") for t, a in _parse(page.read_text(encoding="utf-8")).tags
                 if t == "a"]
        notebook = [h for h in hrefs if h.endswith(f"{name}.ipynb")]
        script = [h for h in hrefs if h.endswith(f"{name}.py")]
        assert notebook and script, name
        nb = nbformat.read(_local(page, notebook[0]), as_version=4)
        nbformat.validate(nb)
        code = "\n".join(c.source for c in nb.cells if c.cell_type == "code")
        assert "WALKTHROUGH =" in code and title.split(" (")[0] in "".join(
            c.source for c in nb.cells if c.cell_type == "markdown")


# --------------------------------------------------------------------------------------------
# The API reference and the other pages


def _public_names(module_name):
    module = importlib.import_module(module_name)
    names = getattr(module, "__all__", None)
    if names is None:
        names = [a for a, o in vars(module).items() if not a.startswith("_")
                 and (inspect.isclass(o) or inspect.isfunction(o)) and o.__module__ == module_name]
    for n in names:                        # a package's __all__ may name its submodules
        if not hasattr(module, n):
            importlib.import_module(f"{module_name}.{n}")
    return module, [n for n in names if not inspect.ismodule(getattr(module, n))]


#: The command line's plumbing (issue 43: out of the API reference): these modules, and in any
#: module the parser builders and ``*_command`` functions.
CLI_MODULES = ("xray_viz.cli", "xray_viz.convert", "xray_viz.scene_options",
               "xray_viz.meshes.command", "xray_viz.montecarlo.command", "xray_viz.viz.command")
CLI_NAMES = re.compile(r"add_\w+_parser|\w+_command|check_scheduler")


@pytest.mark.parametrize("module_name", API_MODULES)
def test_api_reference_has_a_page_per_public_object(site, module_name):
    """Each module's page exists, and each object of its ``__all__`` has a page generated from
    its docstring - under the module that defines it, for a package's re-exports - except the
    command line's parser builders and ``*_command`` functions, which have none."""
    assert site.returncode == 0, site.stderr[-3000:]
    api = site.page("api/generated")
    page = site.page("api/index.html") if module_name == "xray_viz" else api / f"{module_name}.html"
    assert page.is_file(), page
    module, names = _public_names(module_name)
    summary = _plain((inspect.getdoc(module) or "").split("\n")[0])
    assert summary[:24] in _plain("".join(_parse(page.read_text(encoding="utf-8")).text))
    for name in names:
        if CLI_NAMES.fullmatch(name):
            assert not (api / f"{module_name}.{name}.html").exists(), name
            continue
        obj = getattr(module, name)
        owner = getattr(obj, "__module__", module_name) if (
            inspect.isclass(obj) or inspect.isfunction(obj)) else module_name
        qualname = getattr(obj, "__qualname__", name) if owner != module_name else name
        target = api / f"{owner}.{qualname}.html"
        assert target.is_file(), f"{module_name}.{name}: no page {target.name}"


def test_cli_internals_are_not_in_the_api_reference(site):
    """Issue 43: the command line's modules and its parser builders and ``*_command``
    functions have no API pages, and no module page or table lists them; ``xray-viz --help``
    documents the commands."""
    assert site.returncode == 0, site.stderr[-3000:]
    api = site.page("api/generated")
    for module in CLI_MODULES:
        assert not (api / f"{module}.html").exists(), module
    pages = sorted(api.glob("*.html"))
    assert len(pages) > 200
    cli_pages = [p.name for p in pages if CLI_NAMES.fullmatch(p.stem.rsplit(".", 1)[-1])]
    assert cli_pages == []
    listed = set()
    for page in [site.page("api/index.html"), *api.glob("xray_viz.*.html")]:
        tags = _parse(page.read_text(encoding="utf-8"))
        listed |= {a.get("href", "").split("#")[0].rsplit("/", 1)[-1]
                   for t, a in tags.tags if t == "a"}
    assert not {f"{m}.html" for m in CLI_MODULES} & listed
    assert not [h for h in listed if CLI_NAMES.fullmatch(h.removesuffix(".html").rsplit(".", 1)[-1])]
    # the library functions beside them keep their pages
    for name in ("xray_viz.scan.scan", "xray_viz.scan.read_zarr", "xray_viz.transport.transport"):
        assert (api / f"{name}.html").is_file(), name


def _minigallery_links(site, page_name):
    page = site.page(f"api/generated/{page_name}.html")
    html = page.read_text(encoding="utf-8")
    assert "Examples using this" in html, page_name
    after = html.split("Examples using this", 1)[1]
    return {_local(page, a["href"]).relative_to(site.html.resolve()).as_posix()
            for t, a in _parse(after).tags if t == "a" and a.get("href", "").endswith(".html")
            and ("examples/" in a["href"] or "walkthroughs/" in a["href"])}


def test_api_pages_link_to_the_examples_using_them(site):
    """Issue 43: an API page ends with the examples and walkthroughs that call the object,
    under whatever name they call it (``xray_viz.render`` is ``xray_viz.render.render``); each
    link is a page of the site, with its thumbnail."""
    assert site.returncode == 0, site.stderr[-3000:]
    render = _minigallery_links(site, "xray_viz.render.render")
    assert {"examples/plot_your_own_mesh.html", "examples/plot_dicom_nifti_round_trip.html",
            "walkthroughs/08_radiograph.html"} <= render, render
    assert "examples/plot_dose.html" not in render
    assert "examples/plot_dose.html" in _minigallery_links(site, "xray_viz.transport.transport")
    scan = _minigallery_links(site, "xray_viz.scan.scan")
    assert {"examples/plot_drr_dataset_dask.html", "examples/plot_ct_reconstruction.html"} <= scan
    # a class's page: examples that make it or call its methods
    assert "examples/plot_drr_dataset_dask.html" in _minigallery_links(
        site, "xray_viz.orbit.RandomPoses")
    for target in render | scan:
        assert site.page(target).is_file(), target
    page = site.page("api/generated/xray_viz.render.render.html")
    thumbs = [a["src"] for t, a in _parse(page.read_text(encoding="utf-8")).tags
              if t == "img" and "_thumb" in a.get("src", "")]
    assert len(thumbs) >= len(render)
    for src in thumbs:
        _check_png(_local(page, src), min_size=100)


def test_api_pages_render_numpydoc_sections(site):
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page("api/generated/xray_viz.render.render.html").read_text(encoding="utf-8")
    text = "".join(_parse(page).text)
    for section in ("Parameters", "Returns", "Examples"):
        assert section in text
    assert "supersample" in text and "_modules/xray_viz/render.html" in page   # [source]


def test_readme_and_benchmarks_are_pages(site):
    assert site.returncode == 0, site.stderr[-3000:]
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    scene = "".join(_parse(site.page("scene_files.html").read_text(encoding="utf-8")).text)
    physics = "".join(_parse(site.page("physics.html").read_text(encoding="utf-8")).text)
    assert "Unknown keys are errors" in readme and "Unknown keys are errors" in scene
    assert 'response = "energy"' in physics and "mu(E) comes from xraylib" in physics
    # every README sub-heading of a section is a heading of its page, one level up
    html = site.page("physics.html").read_text(encoding="utf-8")
    for sub in re.findall(r"^### (.+)$", readme.split("## Physics keys", 1)[1].split("\n## ")[0],
                          flags=re.M):
        assert re.search(rf"<h2>{re.escape(sub.strip())}<a", html), sub
    page = site.page("benchmarks.html")
    tags = _parse(page.read_text(encoding="utf-8"))
    assert "Targets of issue 3" in "".join(tags.text)
    plots = [a["src"] for t, a in tags.tags if t == "img"]
    # every picture BENCHMARKS.md shows is on the page (and at least the two plots of issue 3)
    shown = len(re.findall(r"!\[", (REPO / "BENCHMARKS.md").read_text(encoding="utf-8")))
    assert len(plots) == shown >= 2
    for src in plots:
        _check_png(_local(page, src))
    arch = "".join(_parse(site.page("architecture.html").read_text(encoding="utf-8")).text)
    assert "Where a CT orbit goes" in arch and "tracing.engines" in arch


def test_how_it_works_has_a_page_per_stage_with_the_equations(site):
    assert site.returncode == 0, site.stderr[-3000:]
    equations = {"scene": [], "rays": ["1.1", "1.2", "1.3-1.4"], "hits": [
        "1.6", "1.7", "1.8", "1.9", "1.10", "1.11", "1.14", "1.15-1.17"], "path_lengths": [],
        "image": []}
    for stage, tags in equations.items():
        html = site.page(f"how_it_works/{stage}.html").read_text(encoding="utf-8")
        assert 'class="math' in html, stage
        for tag in tags:
            assert f"\\tag{{{tag}}}" in html, (stage, tag)


# --------------------------------------------------------------------------------------------
# Offline: nothing comes from the web

_REMOTE = re.compile(r"""<(script|img|iframe|source|embed)\b[^>]*\bsrc\s*=\s*["']?(https?:)?//"""
                     r"""|<link\b[^>]*\bhref\s*=\s*["']?(https?:)?//""", re.I)


def test_pages_load_nothing_from_the_web(site):
    """No page loads a script, stylesheet, font, icon or image from another host; MathJax and
    the vtk.js viewer are copies inside the site."""
    assert site.returncode == 0, site.stderr[-3000:]
    pages = sorted(site.html.rglob("*.html"))
    assert len(pages) > 100
    for page in pages:
        html = page.read_text(encoding="utf-8", errors="replace")
        m = _REMOTE.search(html)
        assert m is None, f"{page.relative_to(site.html)} loads {html[m.start():m.start() + 160]}"
    for css in site.html.rglob("*.css"):
        assert not re.search(r"url\(\s*['\"]?(https?:)?//", css.read_text(errors="replace")), css
    viewer = site.page("_static/static_viewer.html").read_text(encoding="utf-8")
    assert "kitware.github.io/vtk-js/icon" not in viewer
    assert site.page("_static/mathjax/tex-chtml.js").is_file()
    rays = site.page("how_it_works/rays.html").read_text(encoding="utf-8")
    assert re.search(r'<script[^>]+src="[./]*_static/mathjax/tex-chtml\.js', rays)


# --------------------------------------------------------------------------------------------
# In a browser: headless Chromium

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
needs_chromium = pytest.mark.skipif(
    CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/system-deps when root)")


def _chromium(url: str, *args: str, timeout=180) -> subprocess.CompletedProcess:
    profile = tempfile.mkdtemp(prefix="chromium-")
    try:
        cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", "--hide-scrollbars", f"--user-data-dir={profile}",
               "--virtual-time-budget=15000", *args, url]
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    finally:
        shutil.rmtree(profile, ignore_errors=True)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _screenshot(url: str, path: Path, size=(1280, 2000)) -> np.ndarray:
    _chromium(url, f"--screenshot={path}", f"--window-size={size[0]},{size[1]}")
    return np.asarray(Image.open(path).convert("L"), dtype=float)


@needs_chromium
@pytest.mark.parametrize("path", ["index.html", "walkthroughs/08_radiograph.html"])
def test_pages_in_chromium_show_their_images(site, path, tmp_path):
    """The DOM Chromium builds holds the figures, every one a non-blank PNG on disk; the
    screenshot of the page is not blank."""
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page(path)
    dom = _chromium(page.as_uri(), "--dump-dom").stdout
    tags = _parse(dom)
    images = [a["src"] for t, a in tags.tags if t == "img" and a.get("src", "").endswith(".png")]
    figures = [s for s in images if "sphx_glr_" in s and "_thumb" not in s]
    assert figures, f"no figure in {path}"
    if path.startswith("walkthroughs/"):
        assert len(figures) == len(EXPECTED_PNGS[8])
        assert len(_viewer_frames(tags)) == 2
    for src in images:
        _check_png(_local(page, src), min_size=16, min_std=0.0)
    for src in figures:
        _check_png(_local(page, src))
    shot = _screenshot(page.as_uri(), tmp_path / "page.png")
    assert shot.std() > 20, f"{path} renders blank"
    assert (shot < 128).mean() > 0.01                       # text and figures, not white


@needs_chromium
def test_math_is_typeset_offline_in_chromium(site):
    """MathJax (the site's own copy) typesets every equation of a page."""
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page("how_it_works/hits.html")
    n_math = len(re.findall(r'class="math', page.read_text(encoding="utf-8")))
    dom = _chromium(page.as_uri(), "--dump-dom").stdout
    assert n_math > 20
    assert dom.count("<mjx-container") >= n_math
    assert "<mjx-merror" not in dom                         # no TeX error


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def served(site):
    """The built site on an HTTP server at 127.0.0.1 (a free port), for the vtk.js viewer."""
    handler = functools.partial(_Quiet, directory=str(site.html))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=10)


@needs_chromium
def test_interactive_scene_renders_in_chromium(site, served, tmp_path):
    """The interactive tab of a 3D scene: vtk.js draws the exported scene (software WebGL),
    and the page asks for nothing but the local server."""
    assert site.returncode == 0, site.stderr[-3000:]
    page = site.page("walkthroughs/03_viewport_vectors.html")
    (frame,) = _viewer_frames(_parse(page.read_text(encoding="utf-8")))
    url = f"{served}/walkthroughs/{frame}"
    netlog = tmp_path / "net.json"
    shot = _screenshot(url, tmp_path / "scene.png", size=(1000, 700))
    _chromium(f"{served}/walkthroughs/03_viewport_vectors.html", f"--log-net-log={netlog}")
    assert shot.std() > 5, "the vtk.js view is blank"
    assert 0.005 < (shot < 200).mean() < 0.5                # a drawing on a white background
    urls = _page_requests(netlog)
    remote = sorted(u for u in urls if urlsplit(u).hostname not in ("127.0.0.1", "localhost"))
    assert not remote, f"the page asked the web for {remote[:5]}"
    assert any(u.endswith("sphx_glr_03_viewport_vectors_001.vtksz") for u in urls), urls


def _page_requests(netlog: Path) -> set[str]:
    """URLs the pages asked for (Chromium's own requests, initiated by no origin, left out)."""
    log = json.loads(netlog.read_text(encoding="utf-8", errors="replace"))
    start = log["constants"]["logEventTypes"]["URL_REQUEST_START_JOB"]
    return {e["params"]["url"] for e in log["events"]
            if e["type"] == start and e.get("params", {}).get("initiator", "not an origin")
            != "not an origin"}


# --------------------------------------------------------------------------------------------
# The walkthroughs as notebooks


def _jupyter_path(tmp_path) -> Path:
    """A Jupyter data folder with one kernel spec, ``xray_viz``: this interpreter (the one with
    xray_viz installed), whatever ``python`` is first on the PATH."""
    from ipykernel.kernelspec import write_kernel_spec

    data = tmp_path / "jupyter"
    write_kernel_spec(data / "kernels" / "xray_viz", overrides={"display_name": "xray_viz"})
    return data


@pytest.mark.parametrize("number", NOTEBOOKS)
def test_walkthrough_notebook_runs_in_a_kernel(site, number, tmp_path, monkeypatch):
    """The notebook the site offers runs top to bottom in an IPython kernel (nbclient), off
    screen, and writes the figures the script writes."""
    import nbformat
    from nbclient import NotebookClient

    assert site.returncode == 0, site.stderr[-3000:]
    name = dict((n, nm) for n, nm, _ in list_walkthroughs())[number]
    page = site.page(f"walkthroughs/{name}.html")
    (href,) = [a["href"] for t, a in _parse(page.read_text(encoding="utf-8")).tags
               if t == "a" and a.get("href", "").endswith(f"{name}.ipynb")][:1]
    nb = nbformat.read(_local(page, href), as_version=4)
    out = tmp_path / "out"
    monkeypatch.setenv("PYVISTA_OFF_SCREEN", "true")
    monkeypatch.setenv("XRAY_VIZ_OUTPUT", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    monkeypatch.setenv("JUPYTER_PLATFORM_DIRS", "1")
    monkeypatch.delenv("PYVISTA_BUILDING_GALLERY", raising=False)
    monkeypatch.setenv("JUPYTER_PATH", str(_jupyter_path(tmp_path)))
    client = NotebookClient(nb, timeout=600, kernel_name="xray_viz",
                            resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    outputs = "".join(o.get("text", "") for c in nb.cells if c.cell_type == "code"
                      for o in c.get("outputs", []) if o.get("output_type") == "stream")
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.get("output_type") == "error"]
    assert not errors
    assert sorted(p.stem for p in out.glob("*.png")) == sorted(EXPECTED_PNGS[number])
    for png in out.glob("*.png"):
        _check_png(png)
    if number == 1:
        rows = re.findall(r"t = +([\d.]+) .*\|r\(t\) - r0\| = ([\d.]+)", outputs)
        assert len(rows) == 4 and all(float(t) == pytest.approx(float(d)) for t, d in rows)
    if number == 7:
        li = float(re.search(r"line integral = sum mu L = ([\d.]+)", outputs).group(1))
        ratio = float(re.search(r"I/I0 = exp\(-line integral\) = ([\d.]+)", outputs).group(1))
        assert ratio == pytest.approx(np.exp(-li), abs=1e-5)


# --------------------------------------------------------------------------------------------
# The walkthroughs' gallery mode, in this process (what the build relies on)


@pytest.fixture
def gallery_mode(monkeypatch):
    """pyvista.BUILDING_GALLERY as docs/conf.py sets it; no trame export (a picture only)."""
    import pyvista as pv

    def no_trame(self):
        raise ImportError("no trame in this test")

    monkeypatch.setattr(pv, "BUILDING_GALLERY", True)
    monkeypatch.setattr(pv, "OFF_SCREEN", True)
    monkeypatch.setattr(pv.Plotter, "_trame_component", no_trame)
    pv.close_all()
    yield pv
    pv.close_all()


def _block_vars(folder: Path, name="sphx_glr_demo"):
    paths = (str(folder / f"{name}_{k:03d}.png") for k in range(1, 100))
    return {"image_path_iterator": paths, "example_globals": {}}


def test_gallery_plotter_spans_cells_and_keeps_its_slider_frames(gallery_mode, tmp_path,
                                                                 monkeypatch):
    """A figure built over two cells: after the first, nothing is scraped and the plotter stays
    open (the old failure: "This plotter is closed"); after the second, the frame recorded by
    save_frame comes first, then the final scene; no PNG goes to the walkthrough output."""
    from xray_viz.walkthroughs import (gallery_scraper, is_building_gallery, new_plotter,
                                       reset_gallery, save_frame, show_or_save)

    pv = gallery_mode
    monkeypatch.setenv("XRAY_VIZ_OUTPUT", str(tmp_path / "out"))
    conf = {"src_dir": str(tmp_path)}
    assert is_building_gallery()
    plotter = new_plotter(window_size=(400, 300))
    plotter.add_mesh(pv.Sphere(), color="black")
    block_vars = _block_vars(tmp_path)
    assert gallery_scraper(("code", "", 1), block_vars, conf) == ""          # cell 1: open
    assert not plotter._closed and list(pv.plotting.plotter._ALL_PLOTTERS.values()) == [plotter]
    assert save_frame(plotter, "frame", walkthrough=1) is None
    plotter.add_mesh(pv.Cube(center=(2, 0, 0)), color="red")
    plotter.reset_camera()
    assert show_or_save(plotter, "final", walkthrough=1) is None
    rst = gallery_scraper(("code", "", 2), block_vars, conf)                # cell 2: shown
    first, second = tmp_path / "sphx_glr_demo_001.png", tmp_path / "sphx_glr_demo_002.png"
    assert "sphx_glr_demo_001.png" in rst and "sphx_glr_demo_002.png" in rst
    assert rst.index("_001.png") < rst.index("_002.png")
    for png in (first, second):
        _check_png(png, min_size=300, min_std=5.0)
    a = np.asarray(Image.open(first).convert("RGB"), dtype=float)
    b = np.asarray(Image.open(second).convert("RGB"), dtype=float)
    red = lambda im: ((im[..., 0] > 150) & (im[..., 1] < 80)).sum()        # noqa: E731
    assert red(a) == 0 and red(b) > 100            # the frame is before the cube was added
    assert pv.plotting.plotter._ALL_PLOTTERS == {}                          # handed over
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    reset_gallery(conf, None)


def test_gallery_scraper_refuses_a_plotter_closed_unrendered(gallery_mode, tmp_path):
    from xray_viz.walkthroughs import gallery_scraper, new_plotter

    plotter = new_plotter(window_size=(300, 300))
    plotter.close()                                    # closed without show_or_save()
    with pytest.raises(RuntimeError, match="show_or_save"):
        gallery_scraper(("code", "", 1), _block_vars(tmp_path), {"src_dir": str(tmp_path)})


def test_gallery_mode_leaves_matplotlib_figures_open(gallery_mode, tmp_path, monkeypatch):
    from xray_viz.walkthroughs import pyplot, show_or_save_figure

    monkeypatch.setenv("XRAY_VIZ_OUTPUT", str(tmp_path / "out"))
    plt = pyplot()
    fig = plt.figure()
    try:
        assert show_or_save_figure(fig, "fig", walkthrough=1) is None
        assert plt.fignum_exists(fig.number)           # for sphinx-gallery's scraper
        assert not (tmp_path / "out" / "fig.png").exists()
    finally:
        plt.close(fig)


def test_reset_gallery_closes_what_a_walkthrough_left_open(gallery_mode):
    from xray_viz.walkthroughs import new_plotter, reset_gallery

    plotter = new_plotter(window_size=(200, 200))
    reset_gallery({}, None)
    assert plotter._closed and gallery_mode.plotting.plotter._ALL_PLOTTERS == {}
