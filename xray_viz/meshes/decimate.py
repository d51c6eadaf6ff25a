"""Decimation: fewer triangles, a known geometric error.

Quadric edge collapse (pymeshlab, preserving topology, normals and boundary so that a closed
mesh stays closed), either to a target face count or to an error budget: the largest face
count whose symmetric Hausdorff distance to the original stays within ``max_error`` mm, found
by bisection on the face count. The time-vs-error benchmark uses these levels, and
``render(scene, max_error=...)`` (:mod:`xray_viz.lod`) the single collapses of
:func:`collapse`. Vertices stay float64 through pymeshlab (no float32 round trip).

Examples
--------
>>> import trimesh
>>> from xray_viz.meshes.decimate import decimate
>>> ball = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
>>> small, error = decimate(ball, target_faces=1000)
>>> len(small.faces), small.is_watertight, error < 2.0
(1000, True, True)
"""

from __future__ import annotations

import numpy as np

from xray_viz import progress as _progress
from xray_viz.errors import MeshError

__all__ = ["decimate", "collapse", "hausdorff_distance"]


def _meshset(*meshes):
    import pymeshlab

    ms = pymeshlab.MeshSet()
    for m in meshes:
        ms.add_mesh(pymeshlab.Mesh(vertex_matrix=np.asarray(m.vertices, dtype=np.float64),
                                   face_matrix=np.asarray(m.faces, dtype=np.int32)))
    return ms


def hausdorff_distance(a, b, *, samples: int = 20000) -> float:
    """Symmetric Hausdorff distance in mm between two meshes (pymeshlab, sampled).

    Parameters
    ----------
    a, b : trimesh.Trimesh
    samples : int, optional
        Surface samples per direction, besides every vertex.

    Returns
    -------
    float
        ``max(d(a -> b), d(b -> a))`` where ``d(x -> y)`` is the largest distance from a point
        sampled on ``x`` to the surface ``y``.

    Examples
    --------
    >>> import trimesh
    >>> box = trimesh.creation.box(extents=[2, 2, 2])
    >>> bigger = trimesh.creation.box(extents=[2, 2, 3])
    >>> round(hausdorff_distance(box, bigger), 6)
    0.5
    """
    ms = _meshset(a, b)
    d = 0.0
    for s, t in ((0, 1), (1, 0)):
        r = ms.get_hausdorff_distance(sampledmesh=s, targetmesh=t, samplevert=True,
                                      sampleface=True, samplenum=int(samples))
        d = max(d, float(r["max"]))
    return d


def collapse(mesh, target_faces: int):
    """One quadric edge collapse of ``mesh`` to ``target_faces`` faces (topology, normals and
    boundary preserved), in float64 throughout.

    pymeshlab (2025.7) keeps vertices as float64: a vertex the collapse does not move comes
    back bit for bit (``tests/render/test_lod.py`` checks it on a mesh 1 m from the origin, where a
    float32 round trip would move it by ~6e-5 mm).

    Parameters
    ----------
    mesh : trimesh.Trimesh
    target_faces : int

    Returns
    -------
    trimesh.Trimesh
        Not checked for closedness (see :func:`decimate`).

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    >>> len(collapse(ball, 320).faces)
    320
    """
    import trimesh

    ms = _meshset(mesh)
    ms.meshing_decimation_quadric_edge_collapse(
        targetfacenum=int(target_faces), preservenormal=True, preservetopology=True,
        preserveboundary=True, planarquadric=True)
    ms.meshing_remove_unreferenced_vertices()
    m = ms.current_mesh()
    return trimesh.Trimesh(m.vertex_matrix().astype(np.float64),
                           m.face_matrix().astype(np.int64), process=False)


@_progress.tracked("decimating the mesh", unit="trials")
def decimate(mesh, *, target_faces: int | None = None, max_error: float | None = None,
             samples: int = 20000, min_faces: int = 8):
    """Reduce a closed mesh by quadric edge collapse, to a face count or an error budget.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        A closed mesh (repair it first with :func:`~xray_viz.meshes.repair_mesh`).
    target_faces : int, optional
        Number of faces wanted. Give this or ``max_error``.
    max_error : float, optional
        Largest allowed symmetric Hausdorff distance to ``mesh``, in mm. The result is the
        smallest face count found by bisection that stays within it.
    samples : int, optional
        Surface samples for the Hausdorff distance.
    min_faces : int, optional
        Lower end of the bisection.

    Returns
    -------
    mesh : trimesh.Trimesh
        The decimated mesh; ``mesh`` itself when it already has at most the target count.
    hausdorff : float
        Measured symmetric Hausdorff distance to the input, in mm.

    Raises
    ------
    MeshError
        Neither or both of ``target_faces`` and ``max_error`` given, or a bad value, or the
        result is no longer watertight.

    Examples
    --------
    >>> import trimesh
    >>> ball = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    >>> small, error = decimate(ball, max_error=0.5)
    >>> error <= 0.5, len(small.faces) < len(ball.faces)
    (True, True)
    """
    if (target_faces is None) == (max_error is None):
        raise MeshError("decimate: give exactly one of target_faces (a face count) or "
                        "max_error (mm)")
    n = len(mesh.faces)
    if target_faces is not None:
        target_faces = int(target_faces)
        if target_faces < 4:
            raise MeshError(f"decimate: target_faces must be >= 4, got {target_faces}")
        if target_faces >= n:
            return mesh, 0.0
        out = collapse(mesh, target_faces)
        _check_closed(mesh, out)
        return out, hausdorff_distance(mesh, out, samples=samples)

    if not (np.isfinite(max_error) and max_error > 0):
        raise MeshError(f"decimate: max_error must be > 0 mm, got {max_error}")
    best, best_err = mesh, 0.0
    lo, hi = max(int(min_faces), 4), n  # hi always meets the budget (the mesh itself)
    while hi - lo > max(2, hi // 50):  # 2 % resolution in face count
        mid = (lo + hi) // 2
        cand = collapse(mesh, mid)
        err = hausdorff_distance(mesh, cand, samples=samples)
        _progress.advance()
        if err <= max_error and cand.is_watertight:
            best, best_err, hi = cand, err, mid
        else:
            lo = mid
    _check_closed(mesh, best)
    return best, best_err


def _check_closed(original, out):
    if original.is_watertight and not out.is_watertight:
        raise MeshError(f"decimation to {len(out.faces)} faces opened the mesh; "
                        "ask for more faces")
