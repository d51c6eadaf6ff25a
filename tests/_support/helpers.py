"""Shared helpers for the tests: scenes built in code, analytic chords.

In tests/_support/, which pytest puts on ``sys.path`` (pyproject.toml, ``pythonpath``): every
test folder imports it as ``from helpers import ...``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from xray_viz.scene import Body, Detector, Scene, Source

#: The repository's root folder (the tests read its README, BENCHMARKS.md, phantoms/, ...).
REPO = Path(__file__).resolve().parents[2]


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] *= -1
    return q


def make_scene(meshes, *, mu=0.2, source=(0.0, 0.0, 1000.0), center=(0.0, 0.0, -500.0),
               up=(0.0, 1.0, 0.0), shape=(64, 48), pitch=1.0, kind="point", names=None):
    """A scene from trimesh meshes (one body each)."""
    meshes = meshes if isinstance(meshes, (list, tuple)) else [meshes]
    mus = np.broadcast_to(mu, (len(meshes),))
    names = names or [f"b{k}" for k in range(len(meshes))]
    bodies = tuple(Body(name=n, mesh=m, mu=float(u)) for n, m, u in zip(names, meshes, mus))
    return Scene(source=Source(position=source, kind=kind),
                 detector=Detector(center=center, up=up, shape=shape, pitch=pitch),
                 bodies=bodies)


def box_chord(origins, directions, lo, hi, t_max=np.inf):
    """Exact-ish slab-method chord length of rays through an axis-aligned box, clipped to [0, t_max]."""
    o = np.asarray(origins, float)
    d = np.asarray(directions, float)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lo) - o) / d
        t2 = (np.asarray(hi) - o) / d
    zero = d == 0
    inside = (o >= lo) & (o <= hi)
    tn = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
    tf = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
    tn = np.maximum(tn, 0.0)
    tf = np.minimum(tf, t_max)
    return np.where(tf > tn, tf - tn, 0.0), tn, tf


def ellipsoid_chord(origins, directions, center, axes_matrix):
    """Chord of rays through the ellipsoid {center + A x : |x| <= 1}."""
    a_inv = np.linalg.inv(axes_matrix)
    o = (np.asarray(origins) - center) @ a_inv.T
    d = np.asarray(directions) @ a_inv.T
    a = np.sum(d * d, axis=1)
    b = 2 * np.sum(o * d, axis=1)
    c = np.sum(o * o, axis=1) - 1
    disc = b * b - 4 * a * c
    root = np.sqrt(np.maximum(disc, 0))
    chord_t = np.where(disc > 0, root / a, 0.0)
    return chord_t * np.linalg.norm(directions, axis=1)


def icosphere_radii(mesh) -> tuple[float, float]:
    """(inradius, circumradius) of an icosphere centred on the origin."""
    n = mesh.face_normals
    p = mesh.vertices[mesh.faces[:, 0]]
    r_in = float(np.min(np.abs(np.sum(n * p, axis=1))))
    r_out = float(np.max(np.linalg.norm(mesh.vertices, axis=1)))
    return r_in, r_out


def write_scene(tmp: Path, text: str, meshes: dict | None = None) -> Path:
    """Write meshes (name -> trimesh) and a scene TOML into tmp; return the TOML path."""
    for name, mesh in (meshes or {}).items():
        mesh.export(tmp / name)
    path = tmp / "scene.toml"
    path.write_text(text)
    return path


def ball_union_chord(origins, directions, balls) -> np.ndarray:
    """Length of each ray ``origin + t * direction`` inside the union of balls ``(centre, r)``.

    Exact: each ball's chord interval, then the union of the sorted intervals. Directions need
    not be unit vectors (lengths are in the units of the origins).
    """
    origins = np.asarray(origins, float)
    d = np.asarray(directions, float)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    n = len(d)
    if not balls:
        return np.zeros(n)
    lo, hi = [], []
    for c, r in balls:
        rel = np.asarray(c, float) - origins
        along = np.einsum("ij,ij->i", rel, d)
        h = np.sqrt(np.clip(r * r - (np.einsum("ij,ij->i", rel, rel) - along ** 2), 0, None))
        lo.append(np.where(h > 0, along - h, np.inf))
        hi.append(np.where(h > 0, along + h, -np.inf))
    lo, hi = np.array(lo).T, np.array(hi).T
    order = np.argsort(lo, axis=1)
    lo, hi = np.take_along_axis(lo, order, 1), np.take_along_axis(hi, order, 1)
    total, reach = np.zeros(n), np.full(n, -np.inf)
    for k in range(lo.shape[1]):
        total += np.clip(hi[:, k] - np.maximum(lo[:, k], reach), 0, None)
        reach = np.maximum(reach, hi[:, k])
    return total


def run_on_a_terminal(argv, *, env=None, timeout=300):
    """Run ``argv`` with stdin, stdout and stderr on a pseudo-terminal; (status, output)."""
    import os
    import pty
    import subprocess

    master, slave = pty.openpty()
    proc = subprocess.Popen(argv, stdin=slave, stdout=slave, stderr=slave, close_fds=True,
                            env={**os.environ, **(env or {})})
    os.close(slave)
    chunks = []
    try:
        while True:
            try:
                data = os.read(master, 1 << 16)
            except OSError:               # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
        status = proc.wait(timeout=timeout)
    finally:
        os.close(master)
    return status, b"".join(chunks).decode("utf-8", "replace")


def doctest_examples(module) -> int:
    """The number of docstring examples in ``module`` (a module of xray_viz), once it is sure
    that pytest runs them: pyproject.toml's pytest options collect every module of the package
    with ``--doctest-modules``, so the examples run there, once, and a test that wants a module
    to keep its examples counts them rather than running them again (``doctest.testmod``)."""
    import doctest
    import tomllib

    ini = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    assert "--doctest-modules" in ini["addopts"] and "xray_viz" in ini["testpaths"], ini
    assert module.__name__.split(".")[0] == "xray_viz", module.__name__
    return sum(len(test.examples) for test in doctest.DocTestFinder().find(module))
