"""What a transport scores, and how batches add up: bit for bit the same on any number of
threads, processes or Dask workers.

Histories run in batches of :data:`BATCH` (each its own random stream,
``rng.batch_states``), batches in groups of :data:`GROUP`; a group's
tallies are its batches' added in batch order, and the transport's are the groups' added in
group order. Which thread or worker ran a batch changes nothing.

Every number has a standard error from the per-history sums of squares: energy per region,
the detector's energy and each detector pixel (a photon reaches the detector at most once).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Tallies", "BATCH", "GROUP", "TRACK_VERTICES", "run_group", "n_groups"]

#: Histories per batch (one random stream each).
BATCH = 1 << 14
#: Batches per group (one Dask task each).
GROUP = 16
#: Most vertices kept of a recorded track (longer ones keep their first and their end).
TRACK_VERTICES = 256


@dataclass
class Tallies:
    """Sums over histories, in keV: ``dep`` (2, R) per region (0: the world) and its squares,
    ``img``/``img_sq`` (4, H, W), ``totals`` (``loop.TOTALS``)."""

    dep: np.ndarray
    img: np.ndarray
    img_sq: np.ndarray
    totals: np.ndarray
    #: Recorded tracks ``(vertices (k, 3), end)``, in history order (``transport(tracks=N)``).
    tracks: list = field(default_factory=list)

    @classmethod
    def zeros(cls, n_regions: int, shape) -> "Tallies":
        """Empty tallies for ``n_regions`` regions and a ``(W, H)`` detector."""
        w, h = shape
        return cls(np.zeros((2, n_regions)), np.zeros((4, h, w)), np.zeros((4, h, w)),
                   np.zeros(7))

    def add(self, other: "Tallies") -> None:
        """Add ``other`` into these (in place)."""
        self.dep += other.dep
        self.img += other.img
        self.img_sq += other.img_sq
        self.totals += other.totals
        self.tracks.extend(other.tracks)


def n_groups(histories: int, batch: int = BATCH) -> int:
    """Groups of batches that ``histories`` make."""
    return -(-int(histories) // (batch * GROUP))


def _batch(problem: dict, index: int, n_hist: int) -> Tallies:
    from xray_viz.montecarlo.loop import Emission, Scores, Tables, Tracks, Volumes, run_batch
    from xray_viz.montecarlo.rng import batch_states

    p = problem
    t = Tallies.zeros(p["n_regions"], p["shape"])
    state = batch_states(p["seed"], 1, first=index)[0]
    b = p["bvh"]
    tb = p["tables"]
    # voxel volumes and tracks (see run_batch)
    vg = p["voxels"]
    n_trk = max(0, min(p.get("tracks", 0) - index * p["batch"], n_hist))
    trk_xyz = np.zeros((n_trk, TRACK_VERTICES, 3))
    trk_n = np.zeros(n_trk, np.int64)
    trk_end = np.zeros(n_trk, np.int64)
    run_batch(n_hist, state, Emission(p["field"], p["energies"], p["cdf"]),
              (p["world_lo"], p["world_hi"]), b, p["rank_order"],
              Volumes(vg["inv"], vg["dims"], vg["start"], vg["classes"], vg["weights"],
                      vg["region0"], vg["displace"], vg["majorant"]),
              Tracks(trk_xyz, trk_n, trk_end),
              Tables(tb.mu, tb.ln_e0, tb.d_ln_e, tb.sf, tb.ff2_cum, tb.dx),
              Scores(t.dep, t.img, t.img_sq, t.totals), (p["response"], p["grid"]))
    if n_trk:
        from xray_viz.montecarlo.loop import TRACK_ENDS

        t.tracks = [(trk_xyz[k, :trk_n[k]].copy(), TRACK_ENDS[trk_end[k]]) for k in range(n_trk)]
    return t


def run_group(problem: dict, group: int, *, threads: int = 1) -> Tallies:
    """The tallies of group ``group``: its batches (on ``threads`` threads of the library's
    pool), added in batch order."""
    from xray_viz import _threads

    first = group * GROUP
    size = problem["batch"]
    n_batches = -(-problem["histories"] // size)
    batches = list(range(first, min(first + GROUP, n_batches)))
    sizes = [min(size, problem["histories"] - k * size) for k in batches]
    out = Tallies.zeros(problem["n_regions"], problem["shape"])
    for lo in range(0, len(batches), max(threads, 1)):
        chunk = list(zip(batches[lo:lo + threads], sizes[lo:lo + threads]))
        parts = _threads.run_pieces(lambda j: _batch(problem, *chunk[j]), len(chunk))
        for part in parts:
            out.add(part)
    return out
