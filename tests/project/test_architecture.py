"""The import graph of xray_viz is one-way, as ARCHITECTURE.md draws it.

Every ``import`` of the package is read from the source (module level and inside functions,
so lazy imports count too) and the graph is checked: no cycle anywhere, and each layer
imports only the layers below it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from helpers import REPO

PACKAGE = REPO / "xray_viz"


def _modules() -> dict[str, Path]:
    out = {}
    for path in PACKAGE.rglob("*.py"):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> tuple[set[str], set[str]]:
    """``(xray_viz modules, top-level third-party packages)`` imported by one module."""
    ours, theirs = set(), set()
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        targets = []
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            subs = [f"{base}.{a.name}" for a in node.names]
            # ``from package import module`` imports the module (its package's __init__ runs
            # first, as for every import, and is not counted); a name defined in the package
            # itself is an import of the package
            targets = subs + ([base] if any(t not in MODULES for t in subs) else [])
        for t in targets:
            if t.split(".")[0] != "xray_viz":
                theirs.add(t.split(".")[0])
                continue
            while t not in MODULES and "." in t:
                t = t.rsplit(".", 1)[0]
            if t != name and t in MODULES:
                ours.add(t)
    return ours, theirs


GRAPH = {}
THIRD_PARTY = {}
for _name, _path in MODULES.items():
    GRAPH[_name], THIRD_PARTY[_name] = _imports(_name, _path)

#: The one kind of import allowed to point up (issue 37): the model (``scene``) reaches the
#: scene-file module (``scene_file``, which imports the model) only inside functions - the
#: writer behind ``Scene.to_dict``/``to_toml``, the placement keys of ``transform_bodies``, and
#: the re-exports of the reader's names (``xray_viz.scene.load_scene``) - never at module level
#: (``test_the_model_imports_the_scene_file_module_only_lazily``). The graph checked for cycles
#: and layers is the one without these edges.
LAZY_UP = {("xray_viz.scene", "xray_viz.scene_file")}
for _a, _b in LAZY_UP:
    GRAPH[_a].discard(_b)


def _cycles(graph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_the_reader_sees_the_imports_it_must():
    """The checks below mean something: the reader finds known imports, lazy ones included."""
    assert "xray_viz.tracing.engines" in GRAPH["xray_viz.render"]
    assert "xray_viz.bodies" in GRAPH["xray_viz.scene"]                     # a lazy import
    assert "xray_viz.tracing._raster" in GRAPH["xray_viz.tracing.fast"]
    assert "numba" in THIRD_PARTY["xray_viz.tracing.fast"]
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_no_import_cycle():
    assert _cycles(GRAPH) == []


def _module_level_imports(path: Path) -> set[str]:
    """Modules named by the ``import`` statements at a module's top level (not in functions)."""
    out = set()
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return out


def test_the_model_imports_the_scene_file_module_only_lazily():
    """The file module imports the model; the model reaches it only inside functions (the edges
    of ``LAZY_UP``), so importing the model never imports the reader."""
    assert "xray_viz.scene" in GRAPH["xray_viz.scene_file"]
    for a, b in LAZY_UP:
        top = _module_level_imports(MODULES[a])
        assert not any(m == b or m.startswith(b + ".") for m in top), a
        ours, _ = _imports(a, MODULES[a])
        assert b in ours                       # the exception is still needed, else drop it


def test_the_model_re_exports_the_file_names():
    """``xray_viz.scene.load_scene`` (and the other names that moved) are the reader's own."""
    import xray_viz
    from xray_viz import scene, scene_file

    for name in scene._FILE_NAMES:
        assert getattr(scene, name) is getattr(scene_file, name), name
    assert xray_viz.load_scene is scene_file.load_scene
    with pytest.raises(AttributeError):
        scene.no_such_name  # noqa: B018


def _reaches(start: str) -> set[str]:
    seen, todo = set(), [start]
    while todo:
        for w in GRAPH[todo.pop()]:
            if w not in seen:
                seen.add(w)
                todo.append(w)
    return seen


@pytest.mark.parametrize("module, forbidden", [
    # how bodies are imaged knows nothing of the meshes, the tracers or the physics
    ("xray_viz.geometry", ("xray_viz.scene", "xray_viz.bodies", "xray_viz.tracing",
                           "xray_viz.physics", "xray_viz.meshes", "xray_viz.render")),
    # the tracers know rays and triangles, not scenes, images or viewers
    ("xray_viz.tracing", ("xray_viz.scene", "xray_viz.render", "xray_viz.physics",
                          "xray_viz.viz", "xray_viz.output", "xray_viz.cli")),
    ("xray_viz.tracing.engines", ("xray_viz.scene", "xray_viz.render", "xray_viz.physics",
                                  "xray_viz.viz")),
    ("xray_viz.attenuation", ("xray_viz.scene", "xray_viz.render", "xray_viz.tracing.fast",
                              "xray_viz.viz", "xray_viz.physics")),
    # what is imaged does not depend on how it is imaged, nor on the physics
    ("xray_viz.bodies", ("xray_viz.scene", "xray_viz.render", "xray_viz.physics",
                         "xray_viz.tracing.fast", "xray_viz.viz")),
    ("xray_viz.physics.imaging", ("xray_viz.render", "xray_viz.scene", "xray_viz.tracing",
                                  "xray_viz.viz")),
    # the stages' values know acquisitions and bodies, not scenes
    ("xray_viz.physics.beam", ("xray_viz.render", "xray_viz.scene", "xray_viz.tracing",
                               "xray_viz.viz", "xray_viz.physics.imaging")),
    ("xray_viz.physics.detector_model", ("xray_viz.render", "xray_viz.scene",
                                         "xray_viz.tracing", "xray_viz.viz",
                                         "xray_viz.physics.imaging")),
    ("xray_viz.scene", ("xray_viz.render", "xray_viz.tracing.fast", "xray_viz.viz",
                        "xray_viz.output")),
    # reading and writing scene files: above the model, below what renders or writes images
    ("xray_viz.scene_file", ("xray_viz.render", "xray_viz.tracing.fast", "xray_viz.viz",
                             "xray_viz.output", "xray_viz.cli", "xray_viz.scan")),
    ("xray_viz.render", ("xray_viz.viz", "xray_viz.cli", "xray_viz.output")),
])
def test_layers_import_only_what_is_below_them(module, forbidden):
    reached = _reaches(module)
    bad = sorted(m for m in reached for f in forbidden if m == f or m.startswith(f + "."))
    assert bad == [], f"{module} reaches {bad}"


@pytest.mark.parametrize("prefix", ["xray_viz.tracing", "xray_viz.physics",
                                    "xray_viz.attenuation", "xray_viz.geometry",
                                    "xray_viz.bodies"])
def test_no_vtk_in_the_tracer_or_the_physics(prefix):
    """The tracers and the physics run without a render window: no VTK or PyVista import."""
    for name in MODULES:
        if name == prefix or name.startswith(prefix + "."):
            reached = {name} | _reaches(name)
            heavy = {p for m in reached for p in THIRD_PARTY[m]} & {"vtk", "vtkmodules",
                                                                   "pyvista"}
            assert not heavy, f"{name} imports {sorted(heavy)}"


def test_no_module_level_caches_keyed_by_mesh_identity():
    """What is derived from meshes lives on the Bodies that own them (issue 13): no module
    keeps dictionaries keyed by ``id(mesh)``."""
    for name, path in MODULES.items():
        text = path.read_text(encoding="utf-8")
        assert "id(mesh)" not in text and "id(b.mesh)" not in text, name


#: The engines' names as the library spells them (keys of ``tracing.engines.ENGINES``).
ENGINE_NAMES = ("fast", "numpy")


def _engine_name_tests(tree) -> list[int]:
    """Lines where an engine's name is tested or looked up: compared (``== "fast"``, ``in
    ("fast", "numpy")``), used as a subscript (``ENGINES["fast"]``) or as a dictionary key
    (``{"fast": True}``). A name passed on (``engine="fast"``) is not a test."""
    def named(node):
        if isinstance(node, (ast.Tuple, ast.List, ast.Set)):
            return any(named(e) for e in node.elts)
        return isinstance(node, ast.Constant) and node.value in ENGINE_NAMES

    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare) and any(named(x) for x in [node.left,
                                                                    *node.comparators]):
            bad.append(node.lineno)
        elif isinstance(node, ast.Subscript) and named(node.slice):
            bad.append(node.lineno)
        elif isinstance(node, ast.Dict) and any(k is not None and named(k) for k in node.keys):
            bad.append(node.lineno)
    return bad


def test_the_engine_name_reader_finds_the_lookups():
    """The check below means something: it finds each kind of test, and not a name passed on."""
    code = ('a = ENGINES["fast"]\nb = {"numpy": False}\nc = e == "fast"\n'
            'd = e in ("fast", "numpy")\nf = Projector(x, engine="fast")\ng = s["fastest"]\n')
    assert _engine_name_tests(ast.parse(code)) == [1, 2, 3, 4]


def test_no_engine_name_is_tested_outside_the_engines():
    """What an engine can do is a Projector's (or engine's) attribute (issue 37): no
    comparison with, lookup by or table keyed by ``"fast"`` or ``"numpy"`` outside
    ``tracing/engines.py``, over the whole package."""
    bad = [f"{name}:{line}" for name, path in MODULES.items()
           if name != "xray_viz.tracing.engines"
           for line in _engine_name_tests(ast.parse(path.read_text(encoding="utf-8")))]
    assert bad == []


def _field_defaults() -> dict[str, set[str]]:
    """``{field: {default, ...}}`` of every dataclass of the package (defaults as source
    text, ``field(default=x)`` as ``x``); fields without a default are left out."""
    out: dict[str, set[str]] = {}
    for path in MODULES.values():
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not (isinstance(node, ast.ClassDef) and any(
                    "dataclass" in ast.unparse(d) for d in node.decorator_list)):
                continue
            for st in node.body:
                if not (isinstance(st, ast.AnnAssign) and isinstance(st.target, ast.Name)
                        and st.value is not None):
                    continue
                value = st.value
                if isinstance(value, ast.Call) and ast.unparse(value.func).endswith("field"):
                    value = next((k.value for k in value.keywords if k.arg == "default"), None)
                if value is not None:
                    out.setdefault(st.target.id, set()).add(ast.unparse(value))
    return out


FIELD_DEFAULTS = _field_defaults()

#: ``getattr(obj, field, default)`` calls left as they are, the object being legitimately
#: of another type than the dataclass whose field default the call matches:
GETATTR_ALLOWED = {
    # a body, or a voxel volume's class (VoxelMaterial), which has no source file
    ("xray_viz.attenuation", "source_file"), ("xray_viz.bodies", "source_file"),
    # a Scene, an Acquisition or any object with ``source`` and ``detector`` (not a Beam)
    ("xray_viz.geometry", "acquisition"),
    # argparse namespaces of the subcommands, which may lack an option (not ImageMetadata,
    # SceneView, Transport or Detector)
    ("xray_viz.meshes.command", "units"), ("xray_viz.viz.command", "dose"),
    ("xray_viz.viz.command", "volume_style"), ("xray_viz.viz.command", "radiograph"),
    ("xray_viz.viz.command", "seed"),
    # a voxel volume, or a label or mesh volume that has no CT table
    ("xray_viz.viz.scene_view", "table"),
}


def _restated_defaults(tree) -> list[tuple[str, int]]:
    """``(field, line)`` of each ``getattr(obj, "field", default)`` whose default is the
    source text of a dataclass field's own default."""
    out = []
    for n in ast.walk(tree):
        if (isinstance(n, ast.Call) and getattr(n.func, "id", None) == "getattr"
                and len(n.args) == 3 and isinstance(n.args[1], ast.Constant)
                and ast.unparse(n.args[2]) in FIELD_DEFAULTS.get(n.args[1].value, ())):
            out.append((n.args[1].value, n.lineno))
    return out


def test_the_getattr_reader_finds_restated_defaults():
    """The check below means something: it knows the fields' defaults and finds a restatement
    (the detector's ``i0`` and ``response``, the scene's ``volumes``), not other defaults."""
    assert "1.0" in FIELD_DEFAULTS["i0"] and "'energy'" in FIELD_DEFAULTS["response"]
    assert "()" in FIELD_DEFAULTS["volumes"]
    code = ('a = getattr(det, "i0", 1.0)\nb = getattr(det, "i0", 2.0)\n'
            'c = getattr(scene, "volumes", ())\nd = getattr(x, "not_a_field", None)\n')
    assert _restated_defaults(ast.parse(code)) == [("i0", 1), ("volumes", 3)]


def test_no_getattr_default_restates_a_field():
    """Fields are read as fields, not through ``getattr`` with a default that restates the
    dataclass's (issue 37), over the whole package; :data:`GETATTR_ALLOWED` lists the calls
    whose object may be of another type, and each of its entries is still needed."""
    found = {(name, field, line) for name, path in MODULES.items()
             for field, line in _restated_defaults(ast.parse(path.read_text(encoding="utf-8")))}
    assert sorted(f"{n}:{line} {f}" for n, f, line in found
                  if (n, f) not in GETATTR_ALLOWED) == []
    assert GETATTR_ALLOWED <= {(n, f) for n, f, _ in found}


#: The functions of ``tracing/`` and ``physics/`` that take a ``scene``: the documented
#: public adapters over Bodies, Acquisition, Projector, Beam and DetectorModel (issue 37).
SCENE_ADAPTERS = {
    "xray_viz.tracing.engines": {"Engine.__call__", "NumpyEngine.__call__",
                                 "FastEngine.__call__"},      # ENGINES[name](scene, ...)
    "xray_viz.tracing.fast": {"clear_caches", "visible_bodies", "fast_path_lengths",
                              "trace_once", "trace_rows"},
    "xray_viz.tracing.hits": {"trace_rays"},                  # xray_viz.trace_rays, README
    "xray_viz.tracing.reference": {"numpy_path_lengths", "numpy_rows"},
    "xray_viz.physics.dosimetry": {"air_kerma"},              # README
    # the public physics functions, adapters over Beam and DetectorModel (the module says
    # so), and the two helpers that build those values from a scene for them
    "xray_viz.physics.imaging": {
        "_beam_of", "_model", "body_mu", "log_transmission", "log_variance_transmission",
        "pixel_log_transmission", "ray_weights", "transmission", "source_detector_distance",
        "source_object_distance", "magnification", "focal_spot_blur_mm", "falloff_factor",
        "detect", "flat_field", "detect_log"},
}


def _takes_scene(tree) -> set[str]:
    """Qualified names (``Class.method``) of the functions that take a ``scene`` parameter."""
    out = set()

    def visit(node, prefix):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = child.args
                if any(x.arg == "scene" for x in a.posonlyargs + a.args + a.kwonlyargs):
                    out.add(prefix + child.name)
                visit(child, prefix + child.name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(tree, "")
    return out


def test_the_scene_parameter_reader_finds_methods_and_keywords():
    code = ("def a(scene):\n    pass\ndef b(x, *, scene=None):\n    pass\n"
            "class C:\n    def m(self, scene):\n        pass\ndef d(bodies):\n    pass\n")
    assert _takes_scene(ast.parse(code)) == {"a", "b", "C.m"}


@pytest.mark.parametrize("prefix", ["xray_viz.tracing", "xray_viz.physics"])
def test_the_tracers_and_the_physics_take_no_scene(prefix):
    """No function of ``tracing/`` or ``physics/`` takes a ``scene`` (issue 37) but the
    documented public adapters of :data:`SCENE_ADAPTERS`, each of which is still there (an
    adapter that went away leaves the list)."""
    for name, path in MODULES.items():
        if name == prefix or name.startswith(prefix + "."):
            takes = _takes_scene(ast.parse(path.read_text(encoding="utf-8")))
            assert takes == SCENE_ADAPTERS.get(name, set()), name


def test_the_scene_adapters_say_so():
    """Each public adapter's docstring (or its module's, for the physics functions) says it
    is an adapter."""
    import importlib

    for name, functions in SCENE_ADAPTERS.items():
        module = importlib.import_module(name)
        for qual in functions:
            if qual.startswith("_") or qual == "Engine.__call__":
                continue
            obj = module
            for part in qual.split("."):
                obj = getattr(obj, part)
            doc = (obj.__doc__ or "") + (module.__doc__ if name.endswith("imaging") else "")
            assert "adapter" in doc, f"{name}.{qual}"


#: Most parameters a numba function of the library takes (issue 37): more travel as named
#: tuples (the frame, the mesh, the outputs), as ``tracing._raster._raster_bands`` takes them.
MAX_KERNEL_PARAMETERS = 12


def _is_njit(node) -> bool:
    """Whether an expression is ``njit``, ``numba.njit`` or a call of either."""
    if isinstance(node, ast.Call):
        node = node.func
    return (isinstance(node, ast.Name) and node.id == "njit") or (
        isinstance(node, ast.Attribute) and node.attr == "njit")


def _kernels(tree) -> list:
    """The functions a module compiles with numba: decorated with ``njit`` (any form), or
    wrapped by a call ``njit(...)(f)`` anywhere in the module."""
    defs = {n.name: n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
    out = [d for d in defs.values() if any(_is_njit(x) for x in d.decorator_list)]
    for n in ast.walk(tree):
        if (isinstance(n, ast.Call) and isinstance(n.func, ast.Call) and _is_njit(n.func)
                and n.args and isinstance(n.args[0], ast.Name) and n.args[0].id in defs):
            out.append(defs[n.args[0].id])
    return out


def test_the_kernel_reader_finds_the_kernels():
    """The check below means something: it finds kernels of every form."""
    tree = ast.parse(MODULES["xray_viz.tracing._raster"].read_text(encoding="utf-8"))
    names = {d.name for d in _kernels(tree)}
    assert {"_raster_bands", "_cull_triangles", "first_use_rank", "_plane"} <= names
    tree = ast.parse("import numba\n@numba.njit\ndef a(x):\n    pass\n"
                     "def b(x, y):\n    pass\nc = numba.njit(cache=True)(b)\n")
    assert sorted(d.name for d in _kernels(tree)) == ["a", "b"]


def test_no_kernel_takes_more_than_twelve_parameters():
    """Every numba function of the library (kernels and their helpers) takes at most
    :data:`MAX_KERNEL_PARAMETERS` parameters (issue 37): no list of 34 loose arrays and
    scalars whose types sit hundreds of lines away."""
    bad, seen = [], 0
    for name, path in MODULES.items():
        for d in _kernels(ast.parse(path.read_text(encoding="utf-8"))):
            seen += 1
            a = d.args
            n = len(a.posonlyargs + a.args + a.kwonlyargs) + bool(a.vararg) + bool(a.kwarg)
            if n > MAX_KERNEL_PARAMETERS:
                bad.append(f"{name}.{d.name}: {n}")
    assert seen > 50 and bad == []
