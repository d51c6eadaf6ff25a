"""What is imaged: the bodies of a scene, and everything derived from their meshes.

:class:`Bodies` is an immutable sequence of :class:`~xray_viz.scene.Body`. It is built once
per set of meshes (a scene file loaded, meshes handed to the API), and that is when the meshes
are checked and, if needed, repaired (:func:`xray_viz.meshes.repair.ensure_traceable`).
Everything derived from the meshes - the concatenated triangles, bounding boxes, the mesh
reports, which bodies are *simple* (winding number 0 or 1, so a signed depth sum is their path
length), the precedence of overlapping bodies, an engine's own set-up (the fast engine's
spatial order) and its recent results - is computed on first use and kept on the object
(:meth:`Bodies.cached`), never in module-level caches.

How the bodies are imaged - the source and the detector - is the
:class:`~xray_viz.geometry.Acquisition`; a :class:`~xray_viz.scene.Scene` pairs one of each.
Moving the source (a viewer's slider, the next angle of a CT orbit) makes a new acquisition and
keeps the same :class:`Bodies`, so no per-mesh work is paid again. Bodies made from the same
mesh objects (another material, another name) share the mesh-derived data
(:meth:`Bodies.like`); moving the bodies themselves (:meth:`Bodies.transform`) carries over what
an orientation-preserving affine map keeps: the mesh checks, simplicity and precedence.

A mesh changed in place after the bodies were built (``mesh.apply_translation(...)``) is
noticed (trimesh's hash follows its data): what was derived from it is computed again.

Examples
--------
>>> import trimesh
>>> from xray_viz.bodies import Bodies
>>> from xray_viz.scene import Body
>>> outer = Body(name="outer", mesh=trimesh.creation.box(extents=[40, 40, 40]), mu=0.2)
>>> inner = Body(name="inner", mesh=trimesh.creation.box(extents=[10, 10, 10]), mu=1.0)
>>> bodies = Bodies([inner, outer])
>>> bodies.names, bodies.precedence.tolist()     # inner is wholly inside outer: it wins
(['inner', 'outer'], [1, 0])
>>> bodies.bounds.shape
(2, 2, 3)
"""

from __future__ import annotations

import dataclasses
import contextlib
import contextvars
import threading
import warnings
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from xray_viz.errors import MeshError, SceneError, XrayVizError

__all__ = ["Bodies"]

#: The derived-data store whose meshes were found unchanged on entry to a
#: :meth:`Bodies.checked` block (per thread and context): its lookups skip the re-hash.
_CHECKED: contextvars.ContextVar = contextvars.ContextVar("xray_viz_bodies_checked",
                                                          default=None)


def _mesh_hash(mesh):
    """trimesh's hash of the vertex and face data (cached by trimesh until they change), or
    None for a mesh object that has none."""
    try:
        return hash(mesh)
    except TypeError:
        return None


class _Derived:
    """What is derived from one tuple of meshes, shared by every :class:`Bodies` made of those
    mesh objects (the materials and names may differ)."""

    def __init__(self, meshes, reports):
        self.meshes = tuple(meshes)
        self.hashes = tuple(_mesh_hash(m) for m in self.meshes)
        self.reports = reports
        self.lock = threading.RLock()
        self.values: dict = {}                    # named derived data (bounds, precedence, ...)
        self.cache: OrderedDict = OrderedDict()   # an engine's own data (see Bodies.cached)

    def __getstate__(self):
        # Pickled (to another process, a Dask worker): the checks, bounds and precedence
        # travel; the lock and the engines' scratch memory and results do not.
        state = dict(self.__dict__)
        del state["lock"]
        state["cache"] = OrderedDict()
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.lock = threading.RLock()

    def same_meshes(self, meshes) -> bool:
        return len(meshes) == len(self.meshes) and all(
            a is b for a, b in zip(meshes, self.meshes)) and self.unchanged()

    def unchanged(self) -> bool:
        return tuple(_mesh_hash(m) for m in self.meshes) == self.hashes


class Bodies(Sequence):
    """An immutable, checked sequence of bodies with their derived data cached.

    Parameters
    ----------
    bodies : sequence of Body
        Closed meshes filled with one material each; names must be unique.
    where : str, optional
        Prefix of messages (a scene file's path and ``": "``).
    check : bool, optional
        Check every mesh and repair one that is not closed and outward, with a
        :class:`~xray_viz.meshes.repair.MeshRepairWarning` (the default). ``False`` trusts
        the caller (the meshes are checked on first use of :attr:`reports`).
    reports : sequence of MeshReport or None, optional
        The meshes' reports when the caller has just checked them (the scene file loader),
        so they are not checked twice; a None entry is checked here.
    precedence : sequence of int, optional
        The precedence of overlapping bodies (:attr:`precedence`) when the caller knows it:
        bodies moved by an orientation-preserving map, or meshes decimated within a
        tolerance, keep the precedence of the bodies they came from instead of having it
        worked out again from surfaces that may now touch or cross.

    Raises
    ------
    SceneError
        If two bodies share a name.
    MeshError
        If a mesh cannot be made traceable.

    Notes
    -----
    A :class:`Bodies` is a :class:`~collections.abc.Sequence` (``len``, indexing, iteration)
    and compares equal to the tuple of its bodies.
    """

    def __init__(self, bodies=(), *, where: str = "", check: bool = True, reports=None,
                 precedence=None):
        bodies = tuple(bodies)
        names = [b.name for b in bodies]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SceneError(f"{where}body names must be unique, repeated: {dup}")
        if reports is not None:
            reports = tuple(reports)
            if len(reports) != len(bodies):
                raise SceneError("Bodies: one report per body")
        if check or reports is not None:
            known = reports if reports is not None else (None,) * len(bodies)
            checked = [(b, r) if r is not None else _traceable(b, where)
                       for b, r in zip(bodies, known)] if check or None in known else \
                list(zip(bodies, known))
            bodies = tuple(b for b, _ in checked)
            reports = tuple(r for _, r in checked)
        self._bodies = bodies
        self._where = where
        self._d = _Derived([b.mesh for b in bodies], reports)
        if precedence is not None:
            precedence = np.asarray(precedence)
            if precedence.shape != (len(bodies),):
                raise SceneError("Bodies: one precedence per body")
            self._d.values["precedence"] = precedence

    @classmethod
    def like(cls, bodies, other: "Bodies", *, where: str = "") -> "Bodies":
        """Bodies whose meshes are the very mesh objects of ``other`` (unchanged, same order)
        share everything derived from them (reports, precedence, the engines' set-up and
        recent results); other bodies are built and checked as usual.

        Parameters
        ----------
        bodies : sequence of Body
        other : Bodies

        Returns
        -------
        Bodies

        Examples
        --------
        >>> import dataclasses, trimesh
        >>> from xray_viz.scene import Body
        >>> a = Bodies([Body(name="ball", mesh=trimesh.creation.icosphere(), mu=0.2)])
        >>> b = Bodies.like([dataclasses.replace(a[0], mu=0.5)], a)
        >>> b[0].mu, b.precedence is a.precedence
        (0.5, True)
        """
        if isinstance(bodies, Bodies):
            return bodies
        bodies = tuple(bodies)
        if isinstance(other, Bodies) and other._d.same_meshes([b.mesh for b in bodies]):
            out = cls(bodies, where=where, check=False)
            out._d = other._d
            return out
        return cls(bodies, where=where)

    # ------------------------------------------------------------------ sequence protocol
    def __len__(self) -> int:
        return len(self._bodies)

    def __getitem__(self, index):
        return self._bodies[index]

    def __iter__(self):
        return iter(self._bodies)

    def __add__(self, other):
        return self._bodies + tuple(other)

    def __radd__(self, other):
        return tuple(other) + self._bodies

    def __repr__(self) -> str:
        return f"Bodies({', '.join(repr(n) for n in self.names)})"

    def __eq__(self, other):
        if isinstance(other, Bodies):
            return self is other or self._bodies == other._bodies
        if isinstance(other, tuple):
            return self._bodies == other
        return NotImplemented

    __hash__ = object.__hash__

    @property
    def names(self) -> list[str]:
        """The bodies' names, in order."""
        return [b.name for b in self._bodies]

    # ------------------------------------------------------------------ derived data
    def _fresh(self) -> _Derived:
        """The derived-data store, emptied first if a mesh was changed in place."""
        d = self._d
        if d is _CHECKED.get():                  # found unchanged by the enclosing checked()
            return d
        if not d.unchanged():
            with d.lock:
                if not d.unchanged():
                    self._d = d = _Derived(d.meshes, None)
                    d.reports = tuple(_recheck(b, self._where) for b in self._bodies)
        return d

    def _value(self, name, build):
        d = self._fresh()
        with d.lock:
            if name not in d.values:
                value = build()
                if isinstance(value, np.ndarray):
                    value.setflags(write=False)
                d.values[name] = value
            return d.values[name]

    @property
    def reports(self) -> tuple:
        """One :class:`~xray_viz.meshes.repair.MeshReport` per body (computed once)."""
        d = self._fresh()
        if d.reports is None or any(r is None for r in d.reports):
            from xray_viz.meshes.repair import check_mesh

            with d.lock:
                if d.reports is None or any(r is None for r in d.reports):
                    d.reports = tuple(check_mesh(b.mesh) for b in self._bodies)
        return d.reports

    @property
    def simple(self) -> np.ndarray:
        """(n,) bool: bodies whose winding number is provably 0 or 1 everywhere (one piece
        whose surface does not pass through itself, or such outward pieces with disjoint
        bounding boxes), so the signed sum of hit depths along a ray is its length inside
        (:attr:`~xray_viz.meshes.repair.MeshReport.simple`)."""
        return self._value("simple", lambda: np.array([r.simple for r in self.reports], bool))

    @property
    def bounds(self) -> np.ndarray:
        """(n, 2, 3) float: each body's axis-aligned bounding box ``[lo, hi]`` in mm (an empty
        mesh has ``lo = +inf``, ``hi = -inf``)."""
        def build():
            out = np.empty((len(self), 2, 3))
            for k, b in enumerate(self._bodies):
                v = np.asarray(b.mesh.vertices, dtype=np.float64).reshape(-1, 3)
                out[k] = (v.min(axis=0), v.max(axis=0)) if len(v) else (np.inf, -np.inf)
            return out
        return self._value("bounds", build)

    @property
    def triangles(self) -> np.ndarray:
        """(T, 3, 3) float: every triangle of every body, bodies in order."""
        return self._value("triangles", lambda: np.concatenate(
            [b.vertices[b.faces] for b in self._bodies]) if self._bodies else np.zeros((0, 3, 3)))

    @property
    def triangle_body(self) -> np.ndarray:
        """(T,) int: index of the body each triangle of :attr:`triangles` belongs to."""
        return self._value("triangle_body", lambda: np.repeat(
            np.arange(len(self)), [len(b.faces) for b in self._bodies]))

    @property
    def triangle_offset(self) -> np.ndarray:
        """(n + 1,) int: body k owns triangles ``triangle_offset[k]:triangle_offset[k+1]``."""
        return self._value("triangle_offset", lambda: np.concatenate(
            [[0], np.cumsum([len(b.faces) for b in self._bodies])]).astype(np.int64))

    @property
    def precedence(self) -> np.ndarray:
        """(n,) int rank: where bodies overlap, the highest rank gives the material.

        A body wholly inside another wins there (innermost wins); a body meshed from a volume
        (``source_file`` a NIfTI, NRRD, MHA, DICOM file or folder) ranks below every other
        body it does not lie inside (:func:`xray_viz.attenuation.below_meshes`); every other
        overlap goes to the later-listed body. See :func:`xray_viz.attenuation.body_precedence`.
        """
        def build():
            from xray_viz.attenuation import below_meshes, rank_by_nesting
            from xray_viz.meshes._volume_files import is_volume_path
            from xray_viz.meshes.repair import containers

            inside = containers(
                [b.mesh for b in self._bodies], bounds=[(lo, hi) for lo, hi in self.bounds],
                reports=self.reports)
            meshed = [getattr(b, "source_file", None) is not None
                      and is_volume_path(b.source_file) for b in self._bodies]
            return rank_by_nesting(below_meshes(inside, meshed))
        return self._value("precedence", build)

    def cached(self, key, build, *, limit: int = 8, nbytes=None, on_evict=None):
        """An engine's own derived data, built once per key and kept on these bodies.

        Parameters
        ----------
        key : tuple
            Names what is cached; ``key[:2]`` is its *family* (``("fast", "prepared")``).
        build : callable
            ``build()`` makes the value on first use.
        limit : int, optional
            How many values of one family are kept (the least recently used ones are dropped):
            results that depend on an acquisition are bounded this way.
        nbytes : int, optional
            Also drop the least recently used values of the family while together they hold
            more than this many bytes (of NumPy arrays, also inside tuples).
        on_evict : callable, optional
            ``on_evict(value)`` for each value this call drops (after it is dropped): an
            engine may hand its memory on.

        Returns
        -------
        object
        """
        d = self._fresh()
        with d.lock:
            if key in d.cache:
                d.cache.move_to_end(key)
                return d.cache[key]
        value = build()
        dropped = []
        with d.lock:
            d.cache[key] = value
            family = [k for k in d.cache if k[:2] == key[:2]]
            while len(family) > 1 and (len(family) > limit or (
                    nbytes is not None and sum(_bytes(d.cache[k]) for k in family) > nbytes)):
                dropped.append(d.cache.pop(family.pop(0)))
        if on_evict is not None:
            for old in dropped:
                on_evict(old)
        return value

    def lookup(self, key):
        """The value :meth:`cached` holds for ``key``, or None."""
        d = self._fresh()
        with d.lock:
            if key in d.cache:
                d.cache.move_to_end(key)
                return d.cache[key]
        return None

    def store(self, key, value, *, limit: int = 8, nbytes=None, on_evict=None):
        """Keep ``value`` for ``key`` as :meth:`cached` would have built it."""
        return self.cached(key, lambda: value, limit=limit, nbytes=nbytes, on_evict=on_evict)

    def forget(self, family=None) -> None:
        """Drop an engine's cached data (of one ``key[:2]`` family, or all of it): for timing
        cold runs."""
        d = self._d
        with d.lock:
            for k in [k for k in d.cache if family is None or k[:2] == tuple(family)]:
                del d.cache[k]

    @contextlib.contextmanager
    def checked(self):
        """A block in which the meshes are taken as unchanged once found so on entry: each
        lookup of derived data inside it (a traced frame makes about seven) costs no hash of
        every mesh (trimesh's, ~2 us a mesh: 34 us a lookup for the frog's 16 bodies). A mesh
        changed in place inside the block is seen at the next lookup outside it.

        Examples
        --------
        >>> import trimesh
        >>> from xray_viz.scene import Body
        >>> bodies = Bodies([Body(name="ball", mesh=trimesh.creation.icosphere(), mu=0.02)])
        >>> with bodies.checked():
        ...     bool(bodies.simple[0]), len(bodies.bounds)
        (True, 1)
        """
        token = _CHECKED.set(self._fresh())
        try:
            yield self
        finally:
            _CHECKED.reset(token)

    @property
    def lock(self):
        """A re-entrant lock of these bodies' derived data: engines hold it while they use
        scratch memory kept with :meth:`cached`."""
        return self._fresh().lock

    def check_source_outside(self, acquisition, *, where: str = "") -> None:
        """Refuse an acquisition whose rays would start inside one of these bodies.

        A parallel beam's rays start on the source plane (through the source, across the beam);
        a body crossing that plane is refused only where the crossing can lie within the beam
        (the rectangle of the rays' starting points, widened by a pixel). Bounding boxes are
        kept (:attr:`bounds`), so this costs no pass over the vertices for a body wholly in front
        of the source plane or, for a point source, not around the source: a new acquisition
        (the source moved) is checked in microseconds.

        Parameters
        ----------
        acquisition : Acquisition
        where : str, optional
            Prefix of the message (a scene file's path and ``": "``).

        Raises
        ------
        SceneError
            If the point source is inside a body, or a parallel beam's source plane cuts a body
            across the beam.
        """
        from xray_viz.geometry import beam_planes, boxes_outside_beam

        acq = acquisition
        r0 = acq.frame.source
        if not self._bodies:
            return
        parallel = acq.parallel
        boxes = self.bounds
        if not parallel:        # a point source: only the bodies whose box holds it (at once)
            around = np.all((boxes[:, 0] <= r0) & (r0 <= boxes[:, 1]), axis=1)
            for k in np.flatnonzero(around):
                body = self._bodies[k]
                if _winding(body.vertices[body.faces], r0) > 0:
                    raise SceneError(
                        f"{where}the source {r0.tolist()} is inside body {body.name!r}: move "
                        "the source outside every body")
            return
        fr = acq.frame
        forward, eu, ev = fr.depth_axis, fr.project_u, fr.project_v
        if not fr.plain:           # tilted or offset: the source plane from the middle ray
            r0 = fr.source + (fr.middle - fr.center)
        hu, hv = acq.half_widths
        slab = beam_planes(r0, forward, eu, ev, 0.0, hu, hv, False)[:4]
        aside = boxes_outside_beam(boxes[:, 0], boxes[:, 1], r0, slab)
        for k, body in enumerate(self._bodies):
            lo, hi = boxes[k]
            mid, half = (lo + hi) / 2 - r0, (hi - lo) / 2
            centre, reach = float(mid @ forward), float(half @ np.abs(forward))
            if aside[k] or not centre - reach < 0 < centre + reach:
                continue
            v = body.vertices
            depth = (v - r0) @ forward
            if not depth.min() < 0 < depth.max():
                continue
            if _crosses_within(body, v - r0, depth, eu, ev, hu, hv) or \
                    _winding(v[body.faces], r0) > 0:
                raise SceneError(
                    f"{where}body {body.name!r} crosses the plane of the parallel-beam source "
                    f"(through {r0.tolist()}, across the beam): move the source back")

    # ------------------------------------------------------------------ moving them
    def transform(self, matrix, *, changes=None) -> "Bodies":
        """Every body moved by the same affine transform, what it keeps carried over.

        An invertible map that keeps orientation (determinant > 0) keeps every body closed
        and outward, keeps its self-intersections and its simplicity, and keeps which body
        lies inside which, so the mesh reports (volumes scaled by the determinant) and the
        precedence carry over instead of being recomputed.

        Parameters
        ----------
        matrix : (4, 4) array_like
            Homogeneous transform applied to the mesh vertices (mm); last row ``[0, 0, 0, 1]``.
        changes : callable, optional
            ``changes(body, matrix)`` returns other fields of the moved body to replace (a
            dict), such as its placement in the scene file.

        Returns
        -------
        Bodies

        Raises
        ------
        SceneError
            If ``matrix`` is not a finite 4 x 4 affine transform with a positive determinant.

        Examples
        --------
        >>> import numpy as np, trimesh
        >>> from xray_viz.scene import Body
        >>> ball = Bodies([Body(name="ball", mesh=trimesh.creation.icosphere(), mu=0.2)])
        >>> moved = ball.transform(np.array([[1, 0, 0, 5.0], [0, 1, 0, 0],
        ...                                  [0, 0, 1, 0], [0, 0, 0, 1]]))
        >>> moved.bounds[0, :, 0].tolist()
        [4.0, 6.0]
        """
        m = np.asarray(matrix, dtype=float)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)) or not np.allclose(m[3], [0, 0, 0, 1]):
            raise SceneError(f"transform_bodies: need a finite 4 x 4 affine matrix with last row "
                             f"[0, 0, 0, 1], got shape {m.shape}")
        det = float(np.linalg.det(m[:3, :3]))
        if not det > 0:
            raise SceneError(f"transform_bodies: the matrix must keep orientation (determinant "
                             f"> 0), got {det:.6g}; a mirror image would turn meshes inside out")
        moved = []
        for body in self._bodies:
            mesh = body.mesh.copy()
            mesh.apply_transform(m)
            moved.append(dataclasses.replace(body, mesh=mesh,
                                             **(changes(body, m) if changes else {})))
        reports = tuple(dataclasses.replace(r, volume=r.volume * det) for r in self.reports)
        return Bodies(moved, where=self._where, check=False, reports=reports,
                      precedence=self.precedence if len(self) > 1 else None)


def _winding(tris, point) -> int:
    from xray_viz.tracing.hits import PROBE, inside_counts

    return max(inside_counts(tris, point, direction=d)[0]
               for d in (PROBE, np.array([-0.6, 0.48, -0.64])))


def _crosses_within(body, rel, depth, eu, ev, hu, hv) -> bool:
    """Does a face of the body meeting the source plane reach into the beam's rectangle?"""
    f = body.faces
    d = depth[f]
    meet = (d.min(axis=1) <= 0) & (d.max(axis=1) >= 0)
    if not meet.any():
        return False
    tri = rel[f[meet]]
    a, b = tri @ eu, tri @ ev
    return bool(np.any((a.min(axis=1) <= hu) & (a.max(axis=1) >= -hu)
                       & (b.min(axis=1) <= hv) & (b.max(axis=1) >= -hv)))


def _bytes(value) -> int:
    if isinstance(value, np.ndarray):
        return value.nbytes
    if isinstance(value, tuple):
        return sum(_bytes(v) for v in value)
    return 0


def _traceable(body, where: str = ""):
    """``(body, report)``: the body itself when its mesh is closed and outward; else repaired,
    with a warning."""
    from xray_viz.meshes.repair import MeshRepairWarning, check_mesh, ensure_traceable

    report = check_mesh(body.mesh)
    if report.traceable:
        return body, report
    try:
        mesh, changes, report = ensure_traceable(body.mesh, name=body.name, report=report,
                                                 return_report=True)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{exc}") from None
    warnings.warn(f"{where}body {body.name!r}: mesh repaired: {'; '.join(changes)}",
                  MeshRepairWarning, stacklevel=5)
    return dataclasses.replace(body, mesh=mesh), report


def _recheck(body, where: str):
    """The report of a mesh changed in place since its bodies were built; refused if it is no
    longer closed and outward (it cannot be repaired in place)."""
    from xray_viz.meshes.repair import check_mesh

    report = check_mesh(body.mesh)
    if not report.traceable:
        raise MeshError(f"{where}body {body.name!r}: its mesh was changed in place and is now "
                        f"{'; '.join(report.problems())}; build a new Scene from a repaired mesh")
    return report
