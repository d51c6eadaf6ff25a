"""Reading and writing scene files: the TOML tables into a :class:`~xray_viz.scene.Scene`
and back.

:func:`load_scene` reads a scene file (or a bundled phantom, a mesh file alone, a gVirtualXray
JSON scene) and :func:`scene_from_dict` a parsed document: the key lists of each table
(``SOURCE_KEYS``, ``DETECTOR_KEYS``, ``BODY_KEYS``), typed access to a table that reports
unknown keys, a body's placement (``body_transform``). The writer gives the document of a
scene (:meth:`xray_viz.scene.Scene.to_dict`, :meth:`xray_viz.scene.Scene.to_toml`). The
model (:mod:`xray_viz.scene`) does not import this module at module level.

Examples
--------
>>> from xray_viz.scene_file import load_scene
>>> load_scene("sphere").detector.shape
(256, 256)
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np

from xray_viz._toml import plain as _plain
from xray_viz.errors import SceneError, SceneFileNotFoundError, XrayVizError
from xray_viz.physics.spectra import DEFAULT_ENERGY
from xray_viz.scene import (DETECTOR_RESPONSES, LENGTH_UNITS, Body, Detector, Scene, Source,
                            _check_body_values, _is_number, _numbers, _shown, _vec3,
                            check_body_size, check_name, check_pitch)

__all__ = ["load_scene", "scene_from_dict"]


def _path_text(path, base: Path | None) -> str:
    import os

    path = Path(path).resolve()
    if base is None:
        return str(path)
    try:
        return Path(os.path.relpath(path, Path(base).resolve())).as_posix()
    except ValueError:         # another drive: no relative path
        return str(path)


def _with_paths(table: dict, base: Path | None) -> dict:
    """A canonical table (spectrum, mtf) with its file paths written for ``base``."""
    return {k: (_path_text(v, base) if k in ("file", "lsf") and isinstance(v, (str, Path))
                else _plain(v)) for k, v in table.items()}


def _scene_document(scene: "Scene", *, base: Path | None) -> dict:
    src, det = scene.source, scene.detector
    source = {"position": src.position.tolist(), "kind": src.kind}
    if src.spectrum is not None:
        from collections.abc import Mapping

        if not isinstance(src.spectrum, Mapping):
            raise SceneError("[source] spectrum is a Spectrum object built in Python: a scene "
                             "file needs it as a table (such as { kvp = 80.0 }) or a CSV file "
                             "({ file = \"spectrum.csv\" })")
        source["spectrum"] = _with_paths(dict(src.spectrum), base)
    else:
        source["energy"] = src.energy
    if src.mas is not None:
        source["mas"] = src.mas
    source["heel"] = src.heel
    detector = {"center": det.center.tolist()}
    if det.tilted:
        detector.update(u=det.u.tolist(), v=det.v.tolist())
    else:
        detector["up"] = det.up.tolist()
    if det.shifted:
        detector["offset"] = list(det.offset)
    detector.update(shape=list(det.shape), pitch=list(det.pitch), response=det.response)
    if src.mas is None:
        detector["I0"] = det.i0
    detector.update(noise=det.noise, falloff=det.falloff, supersample=det.supersample,
                    focal_spot=det.focal_spot)
    if det.seed is not None:
        detector["seed"] = det.seed
    if det.scintillator is not None:
        detector["scintillator"] = _plain(dict(det.scintillator))
    if det.mtf is not None:
        detector["mtf"] = _with_paths(dict(det.mtf), base)
    detector.update(electronic_noise=det.electronic_noise, gain=det.gain)
    if det.grid is not None:
        detector["grid"] = det.grid.to_dict()
    bodies = []
    for body in scene.bodies:
        if body.shape is not None:                           # a primitive: its table
            entry = {"name": body.name, "shape": _plain(dict(body.shape))}
        else:
            if body.source_file is None:
                raise SceneError(f"body {body.name!r} has no mesh file (its mesh was built in "
                                 "Python): export it (body.mesh.export('NAME.ply')) and give the "
                                 "Body source_file= that file, to write the scene")
            from xray_viz.meshes.io import MESH_SUFFIXES, split_node

            mesh_file = str(split_node(body.source_file)[0])      # model.glb#NODE: the file
            if not mesh_file.lower().endswith(MESH_SUFFIXES):
                raise SceneError(f"body {body.name!r} was made from {Path(mesh_file).name}, not "
                                 "a mesh file: write its meshes with `xray-viz mesh FILE -o "
                                 "FOLDER` and refer to them, to write the scene")
            entry = {"name": body.name, "mesh": _path_text(body.source_file, base)}
        if body.mu is not None:
            entry["mu"] = body.mu
        else:
            entry["material"] = _plain(body.material)
            if body.density is not None:
                entry["density"] = body.density
        entry.update(_plain(dict(body.placement or {})))
        bodies.append(entry)
    doc = {"source": source, "detector": detector}
    if bodies:
        doc["body"] = bodies
    if scene.world is not None:       # the transport's medium
        doc["world"] = {"material": scene.world["material"],
                        "density": float(scene.world["density"])}
    for vol in scene.volumes:       # voxel volumes: their [[ct]] / [[labels]]
        if vol.table is None or vol.source_file is None:
            raise SceneError(f"voxel volume {vol.name!r} was built in Python, not read from a "
                             "[[ct]] or [[labels]] table: save it as NIfTI and refer to it, to "
                             "write the scene")
        kind, table = vol.table
        entry = _plain(dict(table))
        entry.update(file=_path_text(vol.source_file, base), trace="voxels")
        doc.setdefault(kind, []).append(entry)
    return doc


def _compose_placement(placement, matrix):
    """The placement keys of a body's file mesh moved by ``matrix`` as well: a rotation matrix,
    a scale per axis and a position; None when ``matrix`` shears the mesh (no such keys)."""
    p = dict(placement or {})
    rotation = p.get("rotation")
    if rotation is not None:
        rotation = np.asarray(rotation, dtype=np.float64)
    m = np.asarray(matrix, dtype=np.float64) @ body_transform(
        position=p.get("position"), rotation=rotation, scale=p.get("scale"),
        units=p.get("units", "mm"))
    scale = np.linalg.norm(m[:3, :3], axis=0)
    r = m[:3, :3] / scale
    if not (np.allclose(r.T @ r, np.eye(3), atol=1e-9) and np.linalg.det(r) > 0):
        return None
    out = {"position": m[:3, 3].tolist(), "rotation": r.tolist(), "scale": scale.tolist()}
    if "repair" in p:
        out["repair"] = p["repair"]
    return out


# --------------------------------------------------------------------------------------------
# TOML parsing and validation

#: Every key each table of a scene file accepts (an unknown key is an error that lists these).
SOURCE_KEYS = ("position", "kind", "energy", "spectrum", "mas", "heel")
DETECTOR_KEYS = ("center", "up", "shape", "pitch", "size", "response", "I0", "noise", "seed",
                 "falloff", "supersample", "focal_spot", "scintillator", "mtf",
                 "electronic_noise", "gain", "offset", "u", "v", "grid")
BODY_KEYS = ("name", "mesh", "shape", "mu", "material", "density", "position", "rotation",
             "scale", "units", "repair")


class _Table:
    """Typed access to one TOML table that remembers which keys were read."""

    def __init__(self, data, where: str, file: Path | None):
        self.where = where
        self.file = file
        if not isinstance(data, dict):
            self.fail(f"must be a table, got {type(data).__name__}")
        self.data = data
        self.used: set[str] = set()

    def fail(self, msg: str):
        prefix = f"{self.file}: " if self.file else ""
        raise SceneError(f"{prefix}{self.where} {msg}")

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key, *, required=False, default=None):
        self.used.add(key)
        if key not in self.data:
            if required:
                self.fail(f"is missing the required key '{key}'")
            return default
        return self.data[key]

    def number(self, key, *, required=False, default=None, positive=False, nonnegative=False):
        value = self.raw(key, required=required, default=default)
        if value is None or key not in self.data:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(f"{key} must be a number, got {_shown(value)}")
        try:
            value = float(value)
        except OverflowError:                  # an integer beyond float64
            value = math.inf
        if not math.isfinite(value):
            self.fail(f"{key} must be finite, got {value}")
        if positive and value <= 0:
            self.fail(f"{key} must be > 0, got {value:g}")
        if nonnegative and value < 0:
            self.fail(f"{key} must be >= 0, got {value:g}")
        return value

    def string(self, key, *, required=False, default=None, choices=None):
        value = self.raw(key, required=required, default=default)
        if key not in self.data:
            return value
        if not isinstance(value, str):
            self.fail(f"{key} must be a string, got {_shown(value)}")
        if choices is not None and value not in choices:
            self.fail(f"{key} must be one of {', '.join(map(repr, choices))}; got {_shown(value)}")
        return value

    def vector(self, key, n, *, required=False, default=None, positive=False, integer=False):
        value = self.raw(key, required=required, default=default)
        if key not in self.data:
            return value
        ok = isinstance(value, list) and len(value) == n and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        )
        if integer:
            ok = ok and all(isinstance(v, int) for v in value)
        if not ok:
            kind = "integers" if integer else "numbers"
            self.fail(f"{key} must be a list of {n} {kind}, got {_shown(value)}")
        if integer and any(abs(v) >= 2**63 for v in value):
            self.fail(f"{key} must be integers below 2**63, got {_shown(value)}")
        try:
            arr = np.asarray(value, dtype=np.int64 if integer else np.float64)
        except OverflowError:                  # an integer beyond float64
            self.fail(f"{key} must be finite, got {_shown(value)}")
        if not np.all(np.isfinite(arr)):
            self.fail(f"{key} must be finite, got {_shown(value)}")
        if positive and np.any(arr <= 0):
            self.fail(f"{key} must be > 0, got {_shown(value)}")
        return arr

    def scalar_or_vector(self, key, n, *, default=None, positive=False):
        if key in self.data and isinstance(self.data[key], list):
            return self.vector(key, n, positive=positive)
        value = self.number(key, default=default, positive=positive)
        return None if value is None else np.full(n, value)

    def table(self, key, *, required=False):
        value = self.raw(key, required=required, default=None)
        if value is None:
            return None
        return _Table(value, f"{self.where[:-1]}.{key}]" if self.where.endswith("]") else key,
                      self.file)

    def expect(self, keys):
        """Fail now on keys outside ``keys`` (a typo is reported before the key it misspelt)."""
        self.used.update(keys)
        self.done()
        self.used.difference_update(keys)

    def done(self):
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            import difflib

            hints = []
            for key in unknown:
                close = difflib.get_close_matches(key, sorted(self.used), n=1)
                hints.append(f"'{key}'" + (f" (did you mean '{close[0]}'?)" if close else ""))
            self.fail(f"has unknown key{'s' if len(unknown) > 1 else ''} {', '.join(hints)}; "
                      f"known keys: {', '.join(sorted(self.used))}")


def _rotation_matrix(rotation) -> np.ndarray:
    """3x3 rotation from Euler angles in degrees about x, then y, then z (fixed axes)."""
    rotation = np.asarray(rotation, dtype=np.float64)
    if rotation.shape == (3, 3):
        return rotation
    ax, ay, az = np.radians(rotation)
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def body_transform(*, position=None, rotation=None, scale=None, units="mm") -> np.ndarray:
    """4x4 matrix taking mesh coordinates to scene millimetres.

    The mesh is scaled (``units`` then ``scale``), then rotated (degrees about x, y, z in
    that order, fixed axes, or a 3x3 matrix), then translated to ``position``.

    Raises
    ------
    SceneError
        Unknown ``units``, a ``scale`` that is not one or three numbers > 0, a ``position``
        that is not three finite numbers, or a ``rotation`` that is neither three finite
        angles nor a 3 x 3 rotation matrix.

    Examples
    --------
    >>> body_transform(position=[1, 2, 3])[:3, 3].tolist()
    [1.0, 2.0, 3.0]
    """
    if not isinstance(units, str) or units not in LENGTH_UNITS:
        raise SceneError(f"units must be one of {', '.join(map(repr, LENGTH_UNITS))}; "
                         f"got {units!r}")
    m = np.eye(4)
    s = np.ones(3) * LENGTH_UNITS[units]
    if scale is not None:
        factor = _numbers(scale, "scale", 3)
        if not np.all(factor > 0):
            raise SceneError(f"scale must be > 0 (a negative one would mirror the mesh "
                             f"inside out), got {np.asarray(scale).tolist()}")
        s = s * factor
    if rotation is None:
        r = np.eye(3)
    else:
        rot = np.asarray(rotation)
        if rot.shape == (3, 3) and rot.dtype.kind in "iuf" and np.all(np.isfinite(rot)):
            r = _rotation_matrix(rot)
        else:
            r = _rotation_matrix(_numbers(rotation, "rotation (degrees)", 3)
                                 if rot.shape == (3,) else
                                 _numbers(rotation, "rotation (3 angles or a 3 x 3 matrix)", 3))
    m[:3, :3] = r @ np.diag(s)
    if position is not None:
        m[:3, 3] = _vec3(position, name="position")
    return m


def _transform_cause(scale, units, position) -> str:
    """What made a body its size in the scene, for messages: ``"scale 1e-200"``, ..."""
    parts = []
    if scale is not None:
        sc = np.asarray(scale, dtype=np.float64)
        parts.append(f"scale {sc[0]:g}" if np.all(sc == sc[0]) else f"scale {sc.tolist()}")
    if units != "mm":
        parts.append(f"units {units!r}")
    if position is not None:
        parts.append(f"position {np.asarray(position, dtype=np.float64).tolist()}")
    return " with ".join(parts) if parts else "the mesh file's coordinates"


def _distinct_rows(v: np.ndarray) -> int:
    """How many distinct rows (vertices) ``v`` has, exactly (``-0.0 == 0.0``)."""
    if len(v) < 2:
        return len(v)
    v = np.ascontiguousarray(v + 0.0)
    order = np.lexsort(v.T[::-1])
    s = v[order]
    return 1 + int(np.count_nonzero(np.any(s[1:] != s[:-1], axis=1)))


def _place_mesh(mesh, transform, *, where: str, cause: str):
    """The mesh moved by ``transform`` (mm), refusing a result float64 cannot hold: a size out of
    :data:`BODY_SIZE_RANGE`, too small for its distance from the origin, or vertices that the
    transform merged. The mesh itself when ``transform`` is the identity."""
    v0 = np.asarray(mesh.vertices, dtype=np.float64)
    with np.errstate(over="ignore", invalid="ignore", under="ignore"):
        v = v0 @ transform[:3, :3].T + transform[:3, 3]
    check_body_size(v, where=where, cause=cause)
    if np.array_equal(v, v0):
        return mesh
    if len(v) and np.ptp(v, axis=0).max() > 0:
        before, after = _distinct_rows(v0), _distinct_rows(v)
        if after < before:
            raise SceneError(f"{where}{cause} merges {before - after} of the mesh's {before} "
                             f"vertices (they round to the same float64 point): the mesh would "
                             f"collapse; use a larger scale or move it nearer the origin")
    m3 = transform[:3, :3]
    gram = m3.T @ m3
    if not np.allclose(gram, gram[0, 0] * np.eye(3), rtol=1e-9, atol=0):
        # a scale of different factors per axis can flatten a good mesh to zero volume
        from xray_viz.meshes.repair import _is_flat

        volume = float(mesh.volume)
        if not _is_flat(v0, volume) and _is_flat(v, volume * float(np.linalg.det(m3))):
            dims = " x ".join(f"{d:.3g}" for d in np.ptp(v, axis=0))
            raise SceneError(f"{where}{cause} flattens the mesh to {dims} mm, zero volume to "
                             f"rounding: scale the axes by similar factors")
    mesh = mesh.copy()
    mesh.apply_transform(transform)
    return mesh


def _boolean(t: _Table, key: str, default: bool = False) -> bool:
    value = t.raw(key, default=default)
    if not isinstance(value, bool):
        t.fail(f"{key} must be true or false, got {_shown(value)}")
    return value


def _integer(t: _Table, key: str, *, minimum: int, default=None):
    value = t.raw(key, default=default)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        t.fail(f"{key} must be an integer >= {minimum}, got {_shown(value)}")
    return value


def _parse_body(t: _Table, base_dir: Path, index: int):
    """``(body, report)``: one ``[[body]]`` table's body, its mesh checked (and repaired if
    allowed), and the mesh's :class:`~xray_viz.meshes.repair.MeshReport`."""
    from xray_viz.meshes.io import load_mesh, split_node

    t.expect(BODY_KEYS)
    name = t.string("name", default=f"body{index}")
    try:
        check_name(name)
    except SceneError as exc:
        t.fail(f"name: {exc}")
    label = f"(name {name!r})"
    shape = None
    if t.has("shape"):                   # a primitive instead of a mesh file
        from xray_viz.meshes.primitives import check_shape

        if t.has("mesh"):
            t.fail(f"{label} gives both 'mesh' and 'shape'; use one")
        try:
            shape = check_shape(t.raw("shape"))
        except SceneError as exc:
            t.fail(f"{label} {exc}")
        mesh_name = None
    else:
        mesh_name = t.string("mesh", required=True)
        if not mesh_name.strip():
            t.fail(f"{label} mesh must name a mesh file, got {mesh_name!r}")
    mu = t.number("mu")                                  # types here, values in Body's rules
    material = t.raw("material")
    density = t.number("density")
    from xray_viz.errors import MaterialError

    try:
        mu, density = _check_body_values("", mu, material, density)
    except MaterialError as exc:
        t.fail(f"{label}: {exc}")
    except SceneError as exc:
        t.fail(str(exc))
    position = t.vector("position", 3)
    rotation = None
    if t.has("rotation"):
        raw = t.data["rotation"]
        if isinstance(raw, list) and raw and all(isinstance(r, list) for r in raw):
            t.used.add("rotation")
            ok = len(raw) == 3 and all(len(r) == 3 and all(_is_number(x) for x in r) for r in raw)
            rot = np.asarray(raw, dtype=float) if ok else None
            if rot is None or not np.all(np.isfinite(rot)) \
                    or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6) or np.linalg.det(rot) < 0:
                t.fail(f"rotation must be 3 angles in degrees or a 3x3 rotation matrix, got {raw!r}")
            rotation = rot
        else:
            rotation = t.vector("rotation", 3)
    scale = t.scalar_or_vector("scale", 3, positive=True)
    units = t.string("units", default="mm", choices=tuple(LENGTH_UNITS))
    repair = t.raw("repair", default=True)
    if not isinstance(repair, bool):
        t.fail(f"repair must be true or false, got {repair!r}")
    t.done()
    where = f"{t.file}: " if t.file else ""
    if shape is not None:
        from xray_viz.meshes.primitives import shape_mesh

        path = None
        mesh = shape_mesh(shape)
    else:
        path = (base_dir / mesh_name) if not Path(mesh_name).is_absolute() else Path(mesh_name)
        if not Path(mesh_name).is_absolute():    # model.glb#NODE: the node's name kept as is
            mesh_file, node = split_node(path)
            path = mesh_file.resolve() if node is None else Path(f"{mesh_file.resolve()}#{node}")
        try:
            mesh = load_mesh(path)
        except XrayVizError as exc:
            raise type(exc)(f"{where}body {name!r}: {exc}") from None
    try:
        transform = body_transform(position=position, rotation=rotation, scale=scale, units=units)
    except SceneError as exc:
        t.fail(f"{label} {exc}")
    mesh = _place_mesh(mesh, transform, where=f"{where}{t.where} {label} ",
                       cause=_transform_cause(scale if t.has("scale") else None, units, position))
    from xray_viz.meshes.repair import MeshRepairWarning, ensure_traceable

    try:
        mesh, changes, report = ensure_traceable(mesh, name=name, repair=repair,
                                                 return_report=True)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{path.name if path else shape['kind']}: {exc}") from None
    if changes:
        import warnings

        warnings.warn(f"{where}body {name!r} ({path.name if path else shape['kind']}): mesh "
                      f"repaired: {'; '.join(changes)}", MeshRepairWarning, stacklevel=2)
    placement = {k: t.data[k] for k in ("position", "rotation", "scale", "units", "repair")
                 if k in t.data}
    return Body(name=name, mesh=mesh, mu=mu, material=material, density=density,
                source_file=path, placement=placement, shape=shape), report


def _check_material_energies(src: _Table, energy, spectrum, bodies) -> None:
    """Fail when a body of a ``material`` meets photon energies outside the tabulated range of
    the material data (bodies of constant ``mu`` take any energy)."""
    from xray_viz.physics.materials import ENERGY_RANGE

    named = [b for b in bodies if b.material is not None]
    if not named:
        return
    lo, hi = ENERGY_RANGE
    first = named[0]
    who = (f"body {first.name!r} (material {first.material!r})"
           + (f" and {len(named) - 1} more" if len(named) > 1 else ""))
    why = (f"outside {lo:g}-{hi:g} keV, the range of xraylib's attenuation tables that {who} "
           f"needs")
    if spectrum is None:
        e = DEFAULT_ENERGY if energy is None else energy
        if not lo <= e <= hi:
            src.fail(f"energy {e:g} keV is {why}; use an energy in that range, or give such "
                     f"bodies a constant mu (1/cm)")
    elif "file" in spectrum:
        from xray_viz.physics.spectra import read_spectrum_csv

        spec = read_spectrum_csv(spectrum["file"])
        e0, e1 = float(spec.energies[0]), float(spec.energies[-1])
        if e0 < lo or e1 > hi:
            src.fail(f"spectrum file {Path(spectrum['file']).name} spans {e0:g}-{e1:g} keV, "
                     f"{why}; remove its rows outside that range")


def scene_from_dict(doc: dict, *, base_dir: str | Path = ".", file: Path | None = None) -> Scene:
    """Build a :class:`Scene` from a parsed TOML document.

    Parameters
    ----------
    doc : dict
        The parsed document with ``source``, ``detector`` and ``body`` entries.
    base_dir : path-like
        Directory that mesh paths are relative to.
    file : Path, optional
        The file the document came from, named in error messages.
    """
    base_dir = Path(base_dir)
    top = _Table(doc, "scene", file)
    top.expect(("source", "detector", "body", "labels", "ct", "scan", "world"))
    world = top.raw("world")                           # the transport's medium; None: vacuum
    src = top.table("source", required=True)
    src.where = "[source]"
    src.expect(SOURCE_KEYS)
    position = src.vector("position", 3, required=True)
    kind = src.string("kind", default="point", choices=("point", "parallel"))
    spectrum = src.raw("spectrum")
    energy = src.number("energy", default=None if spectrum is not None else DEFAULT_ENERGY,
                        positive=True)
    if spectrum is not None and src.has("energy"):
        src.fail("gives both 'energy' and 'spectrum'; use one")
    mas = src.number("mas", positive=True)
    heel = src.raw("heel", default=False)
    if not isinstance(heel, (bool, str)):
        src.fail(f"heel must be true, false or the anode's side of the image, got {heel!r}")
    src.done()
    if spectrum is not None:
        from xray_viz.errors import SpectrumError
        from xray_viz.physics.spectra import spectrum_from_dict

        try:
            spectrum = spectrum_from_dict(spectrum, base_dir=base_dir)
        except SceneFileNotFoundError as exc:
            raise SceneFileNotFoundError(f"{src.file}: [source] {exc}" if src.file
                                         else f"[source] {exc}") from None
        except SpectrumError as exc:
            src.fail(str(exc))

    det = top.table("detector", required=True)
    det.where = "[detector]"
    det.expect(DETECTOR_KEYS)
    center = det.vector("center", 3, required=True)
    up = det.vector("up", 3, default=np.array([0.0, 1.0, 0.0]))
    if det.has("up") and (det.has("u") or det.has("v")):
        det.fail("gives 'up' and the tilted detector's axes 'u'/'v': use one (with u and v, "
                 "up is v)")
    tilt = {"offset": det.vector("offset", 2, default=(0.0, 0.0)),
            "u": det.vector("u", 3), "v": det.vector("v", 3)}
    shape = det.vector("shape", 2, required=True, integer=True)
    if det.has("pitch") and det.has("size"):
        det.fail("gives both 'pitch' and 'size'; use one")
    if not det.has("pitch") and not det.has("size"):
        det.fail("is missing the required key 'pitch' (mm between rays) or 'size' ([|HO|, |VE|] mm)")
    if det.has("size"):
        size = det.vector("size", 2, positive=True)
        pitch = size / np.maximum(shape - 1, 1)
        what = f"size {size.tolist()} over shape {shape.tolist()} gives a pitch of"
    else:
        pitch = det.scalar_or_vector("pitch", 2, positive=True)
        what = "pitch"
    try:
        check_pitch(pitch, center, what=what)
    except SceneError as exc:
        raise SceneError(f"{det.file}: {exc}" if det.file else str(exc)) from None
    options = {
        "response": det.string("response", default="energy", choices=DETECTOR_RESPONSES),
        "noise": _boolean(det, "noise"),
        "falloff": _boolean(det, "falloff", default=mas is not None),
        "seed": _integer(det, "seed", minimum=0),
        "supersample": _integer(det, "supersample", minimum=1, default=1),
        "focal_spot": det.number("focal_spot", default=0.0, nonnegative=True),
        "electronic_noise": det.number("electronic_noise", default=0.0, nonnegative=True),
        "gain": det.number("gain", default=1.0, positive=True),
    }
    from xray_viz.physics import detector as phys
    from xray_viz.physics.grid import Grid

    for key, parse in (("scintillator", phys.scintillator_from_dict),
                       ("mtf", lambda raw: phys.mtf_from_dict(raw, base_dir=base_dir)),
                       ("grid", Grid.of)):
        try:
            options[key] = None if not det.has(key) else parse(det.raw(key))
        except SceneFileNotFoundError as exc:
            raise SceneFileNotFoundError(f"{det.file}: [detector] {key}: {exc}" if det.file
                                         else f"[detector] {key}: {exc}") from None
        except SceneError as exc:
            det.fail(str(exc))
    if options["noise"] and not det.has("I0") and mas is None:
        det.fail("sets noise = true without 'I0': give the unattenuated photons per pixel, "
                 "e.g. I0 = 10000.0, or [source] mas")
    if mas is not None and det.has("I0"):
        det.fail("gives 'I0' and [source] gives 'mas': use one (with mas, I0 follows from the "
                 "tube output)")
    options["i0"] = det.number("I0", default=1.0, positive=True)
    if mas is not None:
        from xray_viz.errors import SpectrumError
        from xray_viz.physics.dosimetry import centre_pixel_photons

        try:
            options["i0"] = centre_pixel_photons(spectrum, mas, kind=kind, source=position,
                                                 center=center, pitch=pitch)
        except SpectrumError as exc:
            src.fail(str(exc))
    det.done()
    # the value rules are the dataclasses' own: a bad value is reported before any mesh loads
    try:
        source = Source(position=position, kind=kind, energy=energy, spectrum=spectrum, mas=mas,
                        heel=heel)
        detector = Detector(center=center, up=up, shape=tuple(shape.tolist()),
                            pitch=tuple(pitch), **options, **tilt)
    except SceneError as exc:
        raise SceneError(f"{file}: {exc}" if file else str(exc)) from None

    orbit = top.raw("scan")
    if orbit is not None:
        from xray_viz.orbit import orbit_from_dict

        orbit = orbit_from_dict(orbit, base_dir=base_dir, file=file)
    raw_bodies = top.raw("body", default=[])
    if not isinstance(raw_bodies, list):
        top.fail("'body' must be an array of tables: write [[body]]")
    volumes = {key: top.raw(key) for key in ("labels", "ct")}
    top.done()
    from xray_viz.meshes.io import expand_nodes

    raw_bodies = expand_nodes(raw_bodies, base_dir, file=file)  # glTF nodes: a body each
    parsed = []
    for k, raw in enumerate(raw_bodies):
        bt = _Table(raw, f"[[body]] #{k + 1}", file)
        parsed.append(_parse_body(bt, base_dir, k))
    if any(v is not None for v in volumes.values()):  # label maps and CTs: bodies after [[body]]
        from xray_viz.meshes.volumes import volume_bodies

        from xray_viz.volume import VoxelVolume

        made = volume_bodies(volumes, base_dir=base_dir, file=file, body=Body)
        voxels = tuple(b for b in made if isinstance(b, VoxelVolume))   # trace = "voxels"
        parsed.extend((b, None) for b in made if not isinstance(b, VoxelVolume))
    else:
        voxels = ()
    bodies = [b for b, _ in parsed]
    _check_material_energies(src, energy, spectrum, bodies)
    from xray_viz.bodies import Bodies

    try:
        bodies = Bodies(bodies, where=f"{file}: " if file else "",
                        reports=[r for _, r in parsed])
        scene = Scene(source=source, detector=detector, bodies=bodies, path=file,
                      orbit=orbit, world=world, volumes=voxels)
    except SceneError as exc:
        msg = str(exc)
        if file and not msg.startswith(str(file)):
            msg = f"{file}: {msg}"
        raise SceneError(msg) from None
    return scene


def load_scene(path: str | Path) -> Scene:
    """Load a scene from a TOML file, or a bundled phantom by name.

    Parameters
    ----------
    path : str or Path
        A ``.toml`` scene file, or the name of a bundled phantom (see ``xray-viz phantoms``),
        or a mesh file alone (STL, OBJ, PLY, ...: framed with a stated material, see
        :mod:`xray_viz.starter`).
        An existing file is read; otherwise a bare name (no suffix, no folder) is a phantom's
        name, even when a folder of that name exists (``./frog`` names the folder).

    Returns
    -------
    Scene

    Raises
    ------
    SceneFileNotFoundError
        If the file does not exist and no phantom has that name.
    SceneError
        If the file is not valid TOML or not a valid scene (unknown or missing keys, wrong types,
        bad values, ``up`` parallel to the beam, the source inside a body).

    Examples
    --------
    >>> import xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> [body.name for body in scene.bodies]
    ['ball']
    """
    p = Path(path)
    if not p.is_file():
        # a bare name (no suffix, no folder) that is not a file is a phantom's name, even when
        # the working directory has a folder of that name (a phantom's mesh folder, say)
        from xray_viz import phantoms

        bare = not p.suffix and "/" not in str(path) and "\\" not in str(path)
        resolved = phantoms.scene_path(str(path)) if bare else None
        if resolved is not None:
            p = resolved
        elif p.is_dir():
            raise SceneError(f"{p}: is a directory, not a scene file")
        elif not p.exists():
            names = ", ".join(phantoms.names())
            raise SceneFileNotFoundError(
                f"{path}: no such scene file, and no bundled phantom of that name "
                f"(phantoms: {names})"
            )
        else:                                   # a named pipe would block the read for ever
            from xray_viz._files import require_regular

            require_regular(p, SceneError, "scene file")
    from xray_viz.starter import framed_document, is_mesh_file

    if is_mesh_file(p):              # a mesh alone: framed, with a stated material (logged)
        return scene_from_dict(framed_document(p), base_dir=p.parent, file=p)
    if p.suffix.lower() == ".json":  # a gVirtualXray scene
        from xray_viz.meshes.gvxr import gvxr_to_dict, read_json

        return scene_from_dict(gvxr_to_dict(read_json(p), base_dir=p.parent, file=p),
                               base_dir=p.parent, file=p)
    try:
        text = p.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{p}: not a text (UTF-8) TOML file") from None
    except OSError as exc:
        raise SceneError(f"{p}: cannot read: {exc.strerror}") from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        from xray_viz.meshes.gvxr import not_toml

        raise SceneError(not_toml(p, text) or f"{p}: malformed TOML: {exc}") from None
    except RecursionError:
        raise SceneError(f"{p}: nested too deeply (arrays or tables thousands of levels inside each other): not a scene file") from None
    return scene_from_dict(doc, base_dir=p.parent, file=p)
