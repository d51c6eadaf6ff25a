"""What is imaged: the bodies of a scene, and everything derived from their meshes.

:class:`Bodies` is an immutable sequence of :class:`~xray_viz.scene.Body`. It is built once
per set of meshes (a scene file loaded, meshes handed to the API), and that is when the meshes
are checked and, if needed, repaired (:func:`xray_viz.meshes.repair.ensure_traceable`).
Everything the engines derive from the meshes - the concatenated triangles, bounding boxes,
the mesh reports, which bodies are *simple* (winding number 0 or 1, so a signed depth sum is
their path length), the precedence of overlapping bodies, an engine's own set-up (the fast
engine's spatial order) - is computed on first use and kept on the object
(:func:`functools.cached_property`, :meth:`Bodies.cached`), never in module-level caches.

How the bodies are imaged - the source and the detector - is the
:class:`~xray_viz.geometry.Acquisition`; a :class:`~xray_viz.scene.Scene` pairs one of each.
Moving the source (a viewer's slider, the next angle of a CT orbit) makes a new acquisition and
keeps the same :class:`Bodies`, so no per-mesh work is paid again. Moving the bodies themselves
(:meth:`Bodies.transform`) carries over what a rigid or any orientation-preserving affine map
keeps: the mesh checks, simplicity and precedence.

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
import threading
import warnings
from collections import OrderedDict
from collections.abc import Sequence
from functools import cached_property

import numpy as np

from xray_viz.errors import SceneError, XrayVizError

__all__ = ["Bodies"]


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
        the caller (:meth:`transform` of checked bodies).

    Raises
    ------
    SceneError
        If two bodies share a name.
    MeshError
        If a mesh cannot be made traceable.
    """

    def __init__(self, bodies=(), *, where: str = "", check: bool = True):
        bodies = tuple(bodies)
        names = [b.name for b in bodies]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise SceneError(f"{where}body names must be unique, repeated: {dup}")
        self._reports = None
        if check:
            checked = [_traceable(b, where) for b in bodies]
            bodies = tuple(b for b, _ in checked)
            self._reports = tuple(r for _, r in checked)
        self._bodies = bodies
        self._lock = threading.RLock()
        self._cache: OrderedDict = OrderedDict()

    # ------------------------------------------------------------------ sequence protocol
    def __len__(self) -> int:
        return len(self._bodies)

    def __getitem__(self, index):
        if isinstance(index, slice):
            return self._bodies[index]
        return self._bodies[index]

    def __iter__(self):
        return iter(self._bodies)

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
    @property
    def reports(self) -> tuple:
        """One :class:`~xray_viz.meshes.repair.MeshReport` per body (computed once)."""
        if self._reports is None:
            from xray_viz.meshes.repair import check_mesh

            self._reports = tuple(check_mesh(b.mesh) for b in self._bodies)
        return self._reports

    @cached_property
    def simple(self) -> np.ndarray:
        """(n,) bool: bodies whose winding number is provably 0 or 1 everywhere (one piece
        whose surface does not pass through itself, or such outward pieces with disjoint
        bounding boxes), so the signed sum of hit depths along a ray is its length inside."""
        out = np.array([r.simple for r in self.reports], dtype=bool)
        out.setflags(write=False)
        return out

    @cached_property
    def bounds(self) -> np.ndarray:
        """(n, 2, 3) float: each body's axis-aligned bounding box ``[lo, hi]`` in mm (an empty
        mesh has ``lo = +inf``, ``hi = -inf``)."""
        out = np.empty((len(self), 2, 3))
        for k, b in enumerate(self._bodies):
            v = np.asarray(b.mesh.vertices, dtype=np.float64).reshape(-1, 3)
            out[k] = (v.min(axis=0), v.max(axis=0)) if len(v) else (np.inf, -np.inf)
        out.setflags(write=False)
        return out

    @cached_property
    def triangles(self) -> np.ndarray:
        """(T, 3, 3) float: every triangle of every body, bodies in order."""
        if not self._bodies:
            return np.zeros((0, 3, 3))
        tris = np.concatenate([b.vertices[b.faces] for b in self._bodies])
        tris.setflags(write=False)
        return tris

    @cached_property
    def triangle_body(self) -> np.ndarray:
        """(T,) int: index of the body each triangle of :attr:`triangles` belongs to."""
        out = np.repeat(np.arange(len(self)), [len(b.faces) for b in self._bodies])
        out.setflags(write=False)
        return out

    @cached_property
    def triangle_offset(self) -> np.ndarray:
        """(n + 1,) int: body k owns triangles ``triangle_offset[k]:triangle_offset[k+1]``."""
        out = np.concatenate([[0], np.cumsum([len(b.faces) for b in self._bodies])]).astype(
            np.int64)
        out.setflags(write=False)
        return out

    @cached_property
    def precedence(self) -> np.ndarray:
        """(n,) int rank: where bodies overlap, the highest rank gives the material.

        A body wholly inside another wins there (innermost wins); every other overlap goes to
        the later-listed body. See :func:`xray_viz.attenuation.body_precedence`.
        """
        from xray_viz.attenuation import rank_by_nesting
        from xray_viz.meshes.repair import containers

        rank = rank_by_nesting(containers([b.mesh for b in self._bodies], bounds=self.bounds,
                                          reports=self.reports))
        rank.setflags(write=False)
        return rank

    def cached(self, key, build, *, limit: int = 8):
        """An engine's own derived data, built once per key and kept on these bodies.

        Parameters
        ----------
        key : hashable
            Names what is cached (e.g. ``("fast", "prepared", k)``).
        build : callable
            ``build()`` makes the value on first use.
        limit : int, optional
            How many values of the same ``key[0:2]`` family are kept (least recently used
            ones are dropped): results that depend on an acquisition are bounded this way.

        Returns
        -------
        object
        """
        with self._lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        value = build()
        with self._lock:
            self._cache[key] = value
            family = key[:2] if isinstance(key, tuple) else key
            same = [k for k in self._cache
                    if (k[:2] if isinstance(k, tuple) else k) == family]
            for old in same[:-limit] if len(same) > limit else ():
                del self._cache[old]
        return value

    # ------------------------------------------------------------------ moving them
    def transform(self, matrix) -> "Bodies":
        """Every body moved by the same affine transform, what it keeps carried over.

        An invertible map that keeps orientation (determinant > 0) keeps every body closed
        and outward, keeps its self-intersections and its simplicity, and keeps which body
        lies inside which, so the mesh reports (volumes scaled by the determinant) and the
        precedence carry over instead of being recomputed.

        Parameters
        ----------
        matrix : (4, 4) array_like
            Homogeneous transform applied to the mesh vertices (mm); last row ``[0, 0, 0, 1]``.

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
            moved.append(dataclasses.replace(body, mesh=mesh))
        out = Bodies(moved, check=False)
        out._reports = tuple(dataclasses.replace(r, volume=r.volume * det) for r in self.reports)
        if "precedence" in self.__dict__ or len(self) > 1:
            out.__dict__["precedence"] = self.precedence
        return out


def _traceable(body, where: str = ""):
    """``(body, report)``: the body itself when its mesh is closed and outward; else repaired,
    with a warning."""
    from xray_viz.meshes.repair import MeshRepairWarning, check_mesh, ensure_traceable

    report = check_mesh(body.mesh)
    if report.traceable:
        return body, report
    try:
        mesh, changes = ensure_traceable(body.mesh, name=body.name)
    except XrayVizError as exc:
        raise type(exc)(f"{where}{exc}") from None
    warnings.warn(f"{where}body {body.name!r}: mesh repaired: {'; '.join(changes)}",
                  MeshRepairWarning, stacklevel=4)
    return dataclasses.replace(body, mesh=mesh), check_mesh(mesh)
