"""The fast engine's kernels: one explicit specialisation each, threads that do not change a
bit, and the background compilation of the command line (issue 18, cold start).

Timings are in BENCHMARKS.md ("Cold start", ``benchmarks/cold_start.py``), never asserted here.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.tracing import _numba_cache as C
from xray_viz.tracing import _compile, _raster as R, _raster_calls as RC
from xray_viz.tracing import fast
from helpers import make_scene


def _sphere(r=20.0, subdivisions=3, center=(0.0, 0.0, 0.0)):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=r)
    m.apply_translation(center)
    return m


def _every_path():
    """Renders that go through every kernel: one body (direct), one body by bands (single),
    several bodies (multi), a parallel beam and supersampling; and the meshes' spatial order
    by its kernel (a cold start orders them in NumPy instead)."""
    R.KERNELS.kernel("_first_use_rank")
    RC.spatial_order(_sphere().vertices, _sphere().faces)
    fast.fast_path_lengths(xray_viz.load_scene("sphere"), cache=False)
    fast.fast_path_lengths(xray_viz.load_scene("nested_spheres"), supersample=2, cache=False)
    beam = make_scene(_sphere(), kind="parallel", pitch=1.5)
    fast.fast_path_lengths(beam, cache=False)
    old = fast._DIRECT_MAX_SAMPLES
    try:
        fast._DIRECT_MAX_SAMPLES = 0            # one body, traced by bands
        fast.fast_path_lengths(make_scene(_sphere(), pitch=1.5), cache=False)
    finally:
        fast._DIRECT_MAX_SAMPLES = old


def test_every_kernel_has_exactly_its_one_explicit_signature():
    _every_path()
    assert set(R.KERNELS.names()) == set(R.SIGNATURES)
    for name, spec in R.SIGNATURES.items():
        disp = getattr(R, name)
        assert disp.signatures == [R._types(spec)], name
        assert not disp._can_compile, name      # nothing else can be compiled



def test_one_compile_manager_and_plain_calls():
    """The fast engine's kernels and the mesh checks' compile through one
    :class:`~xray_viz.tracing._compile.KernelSet` each; ``_raster`` holds kernels (numba
    dispatchers), their named tuples and data, and no Python function but the signature
    parser, the depth key and the one kernel's source (``first_use_rank``, compiled as
    ``_first_use_rank``); the calls are plain functions of ``_raster_calls``, not objects
    swapped into a module's globals."""
    import inspect

    from xray_viz import _gradient_kernels as G
    from xray_viz.meshes import _check_kernels as K

    for module in (R, K, G):
        assert isinstance(module.KERNELS, _compile.KernelSet)
        assert set(module.KERNELS.signatures) == set(module.SIGNATURES)
        assert all(module.KERNELS.kernels[n] is getattr(module, n) for n in module.SIGNATURES)
    plain = sorted(n for n, v in vars(R).items()
                   if inspect.isfunction(v) and v.__module__ == R.__name__)
    assert plain == ["_types", "depth_key", "first_use_rank"]
    for name in ("first_use_rank", "spatial_order", "project_vertices", "cull_triangles",
                 "cull_and_bin", "raster_single", "raster_multi", "finish", "finish_chunks",
                 "raster_direct", "reduce_chunks"):
        assert inspect.isfunction(getattr(RC, name)) and getattr(RC, name).__module__ == RC.__name__

HELPERS = ("_lowest_bit", "_plane", "_sample_ray", "_obliquity", "exact_cross_sign",
           "beyond_side", "tie_positive", "_clamped", "_axis_code", "_side_value", "_between_samples",
           "_sample_box", "_i32")
EVERY_PATH = """
import json, sys
sys.path.insert(0, sys.argv[1])
import test_cold_start as T
T._every_path()
print(json.dumps({n: len(getattr(T.R, n).signatures) for n in T.HELPERS + tuple(T.R.SIGNATURES)}))
"""


@pytest.mark.slow
def test_helpers_are_specialised_once(tmp_path):
    """In a fresh cache (helpers are compiled only with a kernel that is compiled, not loaded):
    every caller passes a helper the same types, so each is compiled once (``_cover`` no
    longer once per literal mode)."""
    here = os.path.dirname(__file__)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=os.pathsep.join(sys.path))
    out = subprocess.run([sys.executable, "-c", EVERY_PATH, here], env=env, check=True,
                         capture_output=True, text=True, timeout=1200, cwd=here)
    counts = json.loads(out.stdout.splitlines()[-1])
    assert counts == {n: 1 for n in HELPERS + tuple(R.SIGNATURES)}


#: A subprocess's names of every function numba compiles there, in ``compiled``.
LISTEN = """
from numba.core import event
compiled = []
class Listener(event.Listener):
    def on_start(self, ev):
        compiled.append(ev.data["dispatcher"].py_func.__name__)
    def on_end(self, ev):
        pass
event.register("numba:compile", Listener())
"""
COLD_ORDER = """
import hashlib, json, sys
sys.path.insert(0, sys.argv[1])
""" + LISTEN + """import test_cold_start as T
from xray_viz.tracing import _raster as R, _raster_calls as RC, fast
if sys.argv[2] == "worker":       # as the command line: a background process compiles it
    assert R.KERNELS.prepare(["order"], first=["order"]) == ["_first_use_rank"]
L = fast.trace_once(T.make_scene(T._sphere(subdivisions=5), pitch=1.5))
print(json.dumps({"compiled": compiled, "sha": hashlib.sha256(L.tobytes()).hexdigest()}))
"""


def _cold_order(tmp_path, how):
    here = os.path.dirname(__file__)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / how),
               PYTHONPATH=os.pathsep.join(sys.path))     # helpers (tests/_support/)
    run = subprocess.run([sys.executable, "-c", COLD_ORDER, here, how], env=env, check=True,
                         capture_output=True, text=True, timeout=900, cwd=here)
    return json.loads(run.stdout.splitlines()[-1])


def test_a_cold_start_orders_the_meshes_in_numpy_with_the_kernels_bits(tmp_path):
    """While a background process compiles the spatial-order kernel (a cold start of the
    command line), a process orders its meshes in NumPy rather than wait ~1.2 s for it, and
    traces the same bits as a process with the kernel; with no such process (the API, or
    that process killed before it cached the kernel) the kernel is compiled where it is
    needed, so that no later process orders in NumPy again."""
    cold, plain = _cold_order(tmp_path, "worker"), _cold_order(tmp_path, "plain")
    assert "first_use_rank" not in cold["compiled"] and "_raster_direct" in cold["compiled"]
    assert "first_use_rank" in plain["compiled"] and "_raster_direct" in plain["compiled"]
    assert cold["sha"] == plain["sha"]
    again = _cold_order(tmp_path, "plain")     # "plain" cached it: the next process compiles none
    assert (tmp_path / "worker").is_dir() and again["compiled"] == []
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "worker"))
    check = subprocess.run([sys.executable, "-c", "from xray_viz.tracing import _raster as R; "
                            "print(R.KERNELS.is_cached('_first_use_rank'))"], env=env, check=True,
                           capture_output=True, text=True, timeout=300)
    assert check.stdout.split() == ["True"]


@pytest.mark.parametrize("perspective", [True, False])
@pytest.mark.parametrize("grid", [(512, 400), (20000, 30)])      # cell codes, or none
def test_the_numpy_projection_of_a_cold_start_gives_the_kernels_bits(perspective, grid):
    """On a cold start the command line projects the vertices in NumPy
    (:func:`RC.project_vertices_numpy`) rather than compile ``_project_vertices`` first: the
    same snapped coordinates, depths, cell codes, huge flags and depth range, bit for bit,
    also for a vertex at the source, one behind it, a huge one and a NaN one; and the NumPy
    twin is taken only while the kernel is neither compiled nor cached."""
    rng = np.random.default_rng(1)
    V = rng.normal(size=(5000, 3)) * 10
    V[:5] = [[0.1, -0.2, -50.0], [1e30, 0, 0], [np.nan, 0, 0], [5, 5, -60], [0, 0, -50]]
    V = np.ascontiguousarray(V.T)
    frame = (np.array([0.1, -0.2, -50.0]), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]),
             np.array([0.0, 1.0, 0.0]), 37.3, 255.5, 37.3, 200.25, perspective)
    out = []
    for project in (RC.project_vertices, RC.project_vertices_numpy):
        n = V.shape[1]
        arrays = (np.empty((n, 2), np.int64), np.empty(n), np.empty(n, bool),
                  np.empty(n, np.int32))
        wmin, wmax, odd = project(V, *frame, *arrays[:3], *grid, arrays[3])
        out.append((np.array([wmin, wmax]).view(np.int64).tolist(), odd,
                    [a.tobytes() for a in arrays]))
    assert out[0] == out[1] and out[0][1] and out[0][0][0] != out[0][0][1]
    assert not RC._cold("_project_vertices")      # compiled here: the kernel from now on


def test_arguments_of_other_types_are_normalised_not_compiled():
    """int64 faces, non-contiguous and writable inputs reach the one specialisation."""
    scene = make_scene(_sphere(), pitch=1.5)
    ref = fast.trace_once(scene)
    v = np.asarray(scene.bodies[0].vertices, np.float64)
    f = np.asarray(scene.bodies[0].faces, np.int64)
    assert RC._faces(f, len(v)).dtype == np.uint32
    np.testing.assert_array_equal(RC._faces(f, len(v)), f)
    nW = nH = 64
    XY = np.empty((len(v), 2), np.int64)
    w, huge, K = np.empty(len(v)), np.empty(len(v), np.bool_), np.empty(len(v), np.int32)
    wide = np.zeros((6, len(v)))
    wide[::2] = v.T                              # a strided view: not C-contiguous
    RC.project_vertices(wide[::2], np.array([0, 0, 1000.0]), np.array([0, 0, -1.0]),
                        np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 40.0, 31.5, 40.0, 31.5,
                        True, XY, w, huge, nW, nH, K)
    XY2, w2, huge2, K2 = XY.copy(), w.copy(), huge.copy(), K.copy()
    RC.project_vertices(v.T.copy(), np.array([0, 0, 1000.0]), np.array([0, 0, -1.0]),
                        np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 40.0, 31.5, 40.0, 31.5,
                        True, XY2, w2, huge2, nW, nH, K2)
    for a, b in ((XY, XY2), (w, w2), (huge, huge2), (K, K2)):
        np.testing.assert_array_equal(a, b)
    assert len(R._project_vertices.signatures) == 1
    np.testing.assert_array_equal(fast.trace_once(scene), ref)


def test_more_than_2_to_the_31_vertices_is_refused_in_one_line():
    with pytest.raises(SceneError,
                       match=r"2\*\*31 - 1 vertices and triangles; use the NumPy engine"):
        RC._faces(np.zeros((1, 3), np.int64), 2**31)


@pytest.mark.parametrize("pieces", [2, 3, 7])
def test_a_kernel_split_over_threads_gives_the_serial_result_bit_for_bit(monkeypatch, pieces):
    """Every iteration of a split loop writes its own outputs: splitting the range over
    threads changes nothing (projection, then culling with its bounding boxes)."""
    rng = np.random.default_rng(5)
    V = rng.normal(0, 30, (3, 5000))                # coordinate-major, as the kernels take it
    F = rng.integers(0, V.shape[1], (9000, 3)).astype(np.int32)
    r0, f = np.array([0, 0, 1000.0]), np.array([0, 0, -1.0])
    eu, ev = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    planes = np.zeros((4, 4))
    planes[:, 0] = 1.0
    planes[:, 3] = 1e9

    def run(k):
        monkeypatch.setattr(RC, "_threads", lambda: k)
        monkeypatch.setattr(RC, "_MIN_ITEMS", 1)
        n = V.shape[1]
        XY, w = np.empty((n, 2), np.int64), np.empty(n)
        huge, K = np.empty(n, np.bool_), np.empty(n, np.int32)
        RC.project_vertices(V, r0, f, eu, ev, 200.0, 255.5, 200.0, 255.5, True, XY, w, huge,
                            512, 512, K)
        status, box = np.full(len(F), 9, np.int8), np.zeros((len(F), 4), np.int64)
        RC.cull_triangles(F, XY, w, huge, True, 1500.0, 512, 512, status, box, V, r0, planes)
        return XY, w, huge, K, status, box * (status != 0)[:, None]

    serial, split = run(1), run(pieces)
    assert (serial[4] != 0).sum() > 1000         # the test covers triangles
    for a, b in zip(serial, split):
        np.testing.assert_array_equal(a, b)


def test_a_background_compile_is_announced_when_first_needed():
    """Not on entry (a command that refuses its input says only that), but when a kernel of
    the background processes is first needed; once."""
    seen = []
    C.background_compile(R._first_use_rank)
    with C.on_first_compile(seen.append):
        assert seen == []
        C.needs_background()
        C.needs_background()
    with C.on_first_compile(seen.append):       # said once
        C.needs_background()
    assert seen == [C.cache_path(R._first_use_rank)]


PREPARE = """
import json, sys
""" + LISTEN + """from xray_viz.tracing import _raster as R, _raster_calls as RC
started = R.KERNELS.prepare(["setup"])
again = R.KERNELS.prepare(["setup"])             # already being compiled: nothing more
names = R.KERNELS.compile(["setup"])
hits = {n: sum(getattr(R, n).stats.cache_hits.values()) for n in names}
print(json.dumps(dict(started=started, again=again, compiled=compiled, hits=hits,
                      late=R.KERNELS.prepare(["setup"]))))
"""


@pytest.mark.slow
def test_prepare_compiles_in_other_processes_and_this_one_loads(tmp_path):
    """In a fresh cache: prepare() starts workers for the missing kernels; this process
    compiles nothing and loads them from the cache; a second process finds them cached."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = [json.loads(subprocess.run([sys.executable, "-c", PREPARE], env=env, check=True,
                                     capture_output=True, text=True, timeout=600).stdout)
           for _ in range(2)]
    first, second = out
    assert sorted(first["started"]) == sorted(R.PATHS["setup"])
    assert first["again"] == [] and first["late"] == []
    assert first["compiled"] == []               # neither kernel nor helper compiled here
    assert all(h == 1 for h in first["hits"].values()), first
    assert second["started"] == [] and second["compiled"] == []


SHARED = """
import dataclasses, hashlib, json, sys
from numba.core import config, event
compiled = {}
class Listener(event.Listener):
    def on_start(self, ev):
        compiled[ev.data["dispatcher"].py_func.__name__] = int(config.OPT)
    def on_end(self, ev):
        pass
event.register("numba:compile", Listener())
import xray_viz
from xray_viz.tracing import _raster as R, _raster_calls as RC, fast
first = ["setup", "banded", "multi"]                  # the frog's, as the command line
started = R.KERNELS.prepare(first=first)
worker = sorted(R.KERNELS.urgent)
scene = xray_viz.load_scene("default")
scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(48, 40)))
L = fast.trace_once(scene)
for proc in {id(p): p for p in R.KERNELS.workers.values()}.values():
    proc.wait()                                       # its other kernels, into the cache
print(json.dumps({"started": started, "mine": sorted(R.KERNELS.mine), "worker": worker,
                  "compiled": compiled, "sha": hashlib.sha256(L.tobytes()).hexdigest(),
                  "cached": [n for n in R.SIGNATURES if not R.KERNELS.is_cached(n)]}))
"""


@pytest.mark.slow
def test_a_cold_start_shares_the_urgent_kernels_with_one_background_process(tmp_path):
    """The command line's cold start: one background process compiles the costliest urgent
    kernels, this one the rest when it needs them (at the background's optimisation level),
    and neither compiles what the other does; the image has the bits of a warm process's, and
    every kernel ends up cached (the background process compiles the others afterwards)."""
    import dataclasses
    import hashlib

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    env.pop("NUMBA_OPT", None)
    run = subprocess.run([sys.executable, "-c", SHARED], env=env, check=True,
                         capture_output=True, text=True, timeout=900)
    out = json.loads(run.stdout.splitlines()[-1])
    urgent = set(R.KERNELS.names(["setup", "banded", "multi"]))
    assert sorted(out["started"]) == sorted(R.SIGNATURES)
    assert out["mine"] and out["worker"] and set(out["mine"]) | set(out["worker"]) == urgent
    assert not set(out["mine"]) & set(out["worker"])
    assert "_raster_bands" in out["worker"]            # the costliest one
    cost = {n: c for unit, c in R._COSTS.items() for n in unit}
    gap = sum(cost[n] for n in out["worker"]) - sum(cost[n] for n in out["mine"])
    assert abs(gap - R._HEAD) <= max(cost[n] for n in urgent), gap     # balanced, head start
    kernels = {n: opt for n, opt in out["compiled"].items() if n in R.SIGNATURES}
    # this process's share, but for the projection, which it does in NumPy (the same bits)
    # while the kernel is not cached: the background process caches it afterwards
    assert "_project_vertices" in out["mine"]
    assert kernels == {n: R._WORKER_OPT for n in out["mine"] if n != "_project_vertices"}
    assert out["cached"] == []
    scene = xray_viz.load_scene("default")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(48, 40)))
    assert out["sha"] == hashlib.sha256(fast.trace_once(scene).tobytes()).hexdigest()


def test_prepare_starts_nothing_when_only_other_scenes_kernels_are_missing(tmp_path):
    """Kernels missing only outside ``first`` (a worker of an earlier command is compiling
    them): no second worker, and no compile notice (``_numba_cache`` is not told)."""
    code = ("import json; from xray_viz.tracing import _raster as R, _numba_cache as C; "
            "print(json.dumps([R.KERNELS.prepare(['setup'], first=['multi']), C._background, "
            "[R.KERNELS.is_cached(n) for n in R.PATHS['setup']]]))")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", code], env=env, check=True,
                         capture_output=True, text=True, timeout=600)
    assert json.loads(out.stdout) == [[], [], [False] * len(R.PATHS["setup"])]


RENDER_MODULES = """
import json, sys
from xray_viz import cli
code = cli.main(["-q", "render", "sphere", "-o", sys.argv[1], "--shape", "32", "32"])
render = sorted(sys.modules)
cli.build_parser()
print(json.dumps({"code": code, "modules": render, "parser": sorted(sys.modules)}))
"""

#: Modules of other commands than ``render``, which its own parser does not import.
OTHER_COMMANDS = ("xray_viz.viz.command", "xray_viz.scan", "xray_viz.reconstruct",
                  "xray_viz.convert", "xray_viz.walkthroughs", "xray_viz.meshes.command")


def test_the_render_command_imports_no_viewer(tmp_path):
    """``xray-viz render`` renders without importing PyVista or VTK (the viewer's, ~0.5 s of
    every render's start), nor the other commands' modules (it builds its own sub-parser
    only); the whole parser (``show`` among its commands) imports no viewer either."""
    out = subprocess.run([sys.executable, "-c", RENDER_MODULES, str(tmp_path / "x.npy")],
                         check=True, capture_output=True, text=True, timeout=600)
    result = json.loads(out.stdout.splitlines()[-1])
    assert result["code"] == 0 and (tmp_path / "x.npy").is_file()
    assert "xray_viz.tracing._raster" in result["modules"]
    assert [m for m in OTHER_COMMANDS if m in result["modules"]] == []
    assert set(OTHER_COMMANDS) <= set(result["parser"])     # the test can fail
    for modules in (result["modules"], result["parser"]):
        viewer = [m for m in modules if m.split(".")[0] in ("pyvista", "vtk", "vtkmodules")
                  or m == "xray_viz.viz.scene_view"]
        assert viewer == []


def test_the_viewer_is_still_found_where_it_was():
    from xray_viz import viz
    from xray_viz.viz import scene_view

    assert viz.plot_scene is scene_view.plot_scene and viz.SceneView is scene_view.SceneView
    with pytest.raises(AttributeError):
        viz.no_such_thing  # noqa: B018


SUBMODULE_ACCESS = """
import json, sys
import xray_viz
before = sorted(m for m in sys.modules if m.startswith("xray_viz."))
found = {}
for name in sys.argv[1:]:
    found[name] = getattr(xray_viz, name).__name__
print(json.dumps({"before": before, "found": found}))
"""


def test_every_submodule_is_an_attribute_without_an_import():
    """``import xray_viz`` then ``xray_viz.attenuation.path_lengths(...)`` works as it did when
    the package imported everything (walkthrough 08 does this): each public module on disk is
    reached by attribute access in a fresh process and is imported only then."""
    pkg = os.path.dirname(xray_viz.__file__)
    # modules whose attribute is their function
    functions = {"render", "scan", "reconstruct", "transport"}
    on_disk = {n[:-3] if n.endswith(".py") else n for n in os.listdir(pkg)
               if not n.startswith("_") and (n.endswith(".py")
                                             or os.path.isfile(os.path.join(pkg, n, "__init__.py")))}
    public = sorted(on_disk - functions)
    assert {"attenuation", "physics", "tracing", "viz"} <= set(public)   # the listing works
    out = subprocess.run([sys.executable, "-c", SUBMODULE_ACCESS, *public], check=True,
                         capture_output=True, text=True, timeout=600)
    result = json.loads(out.stdout.splitlines()[-1])
    assert result["found"] == {n: f"xray_viz.{n}" for n in public}
    assert "xray_viz.attenuation" not in result["before"]       # imported on first use only
    assert callable(xray_viz.render) and callable(xray_viz.scan)
    with pytest.raises(AttributeError):
        xray_viz.no_such_module  # noqa: B018


WORKER_THEN = """
import sys
exec(compile({worker!r}, "worker", "exec"))
print(" ".join(sorted(m for m in sys.modules if m.startswith("xray_viz"))), flush=True)
"""
IS_CACHED = """
from xray_viz.tracing import _raster as R, _raster_calls as RC
print(R.KERNELS.is_cached("_first_use_rank"), R.KERNELS.is_cached("_reduce_chunks"))
"""


def test_a_worker_imports_only_the_engine_and_caches_for_the_parent(tmp_path):
    """A background worker runs neither ``xray_viz/__init__`` nor ``tracing/__init__`` (which
    import the whole library): numba and the kernels' module only; what it compiles there is
    found in the cache by a process that imported xray_viz as usual."""
    root = os.path.dirname(os.path.dirname(R.__file__))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    out = subprocess.run([sys.executable, "-c", WORKER_THEN.format(worker=_compile.WORKER), root,
                          "xray_viz.tracing._raster", "", "10", "_first_use_rank"], env=env, check=True, capture_output=True,
                         text=True, timeout=600)
    said, modules = out.stdout.split("\n")[:2]
    assert said == "_first_use_rank"
    assert modules.split() == ["xray_viz", "xray_viz.tracing", "xray_viz.tracing._compile",
                               "xray_viz.tracing._numba_cache", "xray_viz.tracing._primitives",
                               "xray_viz.tracing._raster"]
    out = subprocess.run([sys.executable, "-c", IS_CACHED], env=env, check=True,
                         capture_output=True, text=True, timeout=600)
    assert out.stdout.split() == ["True", "False"]


#: Two modules of the package, a kernel in one calling (inlining) a helper of the other: run
#: once per process with a shared cache (``argv``: the modules' folder).
CALLEE = """
import importlib.util, sys
import xray_viz.tracing._numba_cache
def load(name):
    spec = importlib.util.spec_from_file_location("xray_viz." + name, sys.argv[1] + "/" + name + ".py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
load("probe_helper")
kernel = load("probe_kernel").kernel
print(kernel(2.0), len(kernel.stats.cache_hits))
"""
PROBE_KERNEL = """
from numba import njit
from xray_viz.probe_helper import helper
@njit(cache=True)
def kernel(x):
    return helper(x) + 1.0
"""


def test_a_changed_helper_of_another_module_is_not_loaded_stale(tmp_path):
    """numba keys a cached kernel by its own file: the key of xray_viz's kernels also holds
    the sources of the numba functions they call in other modules (the tie rule's
    ``tracing._primitives``), so that the kernel is compiled again when one changes."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    (tmp_path / "probe_kernel.py").write_text(PROBE_KERNEL)

    def run(helper):
        (tmp_path / "probe_helper.py").write_text(
            f"from numba import njit\n@njit(cache=True)\ndef helper(x):\n    return {helper}\n")
        out = subprocess.run([sys.executable, "-c", CALLEE, str(tmp_path)], env=env, check=True,
                             capture_output=True, text=True, timeout=600)
        value, hits = out.stdout.split()
        return float(value), int(hits)

    assert run("x * 10.0") == (21.0, 0)       # compiled
    assert run("x * 10.0") == (21.0, 1)       # loaded
    assert run("x * 100.0") == (201.0, 0)     # the helper changed: compiled again, not 21
    assert C.callee_files(R._tie_biases.py_func) == {
        os.path.join(os.path.dirname(R.__file__), "_primitives.py")}
