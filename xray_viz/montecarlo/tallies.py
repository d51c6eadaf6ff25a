"""What a transport scores, and how batches add up: bit for bit the same on any number of
threads, processes or Dask workers.

Histories run in batches of :data:`BATCH` (each its own random stream,
:func:`~xray_viz.montecarlo.rng.batch_states`), batches in groups of :data:`GROUP`; a group's
tallies are its batches' added in batch order, and the transport's are the groups' added in
group order. Which thread or worker ran a batch changes nothing.

Every number has a standard error from the per-history sums of squares: energy per region,
the detector's energy and each detector pixel (a photon reaches the detector at most once).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Tallies", "Transport", "BATCH", "GROUP", "run_group", "n_groups"]

#: Histories per batch (one random stream each).
BATCH = 1 << 14
#: Batches per group (one Dask task each).
GROUP = 16


@dataclass
class Tallies:
    """Sums over histories, in keV: ``dep`` (2, R) per region (0: the world) and its squares,
    ``img``/``img_sq`` (4, H, W), ``totals`` (:data:`xray_viz.montecarlo.loop.TOTALS`)."""

    dep: np.ndarray
    img: np.ndarray
    img_sq: np.ndarray
    totals: np.ndarray

    @classmethod
    def zeros(cls, n_regions: int, shape) -> "Tallies":
        """Empty tallies for ``n_regions`` regions and a ``(W, H)`` detector."""
        w, h = shape
        return cls(np.zeros((2, n_regions)), np.zeros((4, h, w)), np.zeros((4, h, w)),
                   np.zeros(6))

    def add(self, other: "Tallies") -> None:
        """Add ``other`` into these (in place)."""
        self.dep += other.dep
        self.img += other.img
        self.img_sq += other.img_sq
        self.totals += other.totals


def n_groups(histories: int, batch: int = BATCH) -> int:
    """Groups of batches that ``histories`` make."""
    return -(-int(histories) // (batch * GROUP))


def _batch(problem: dict, index: int, n_hist: int) -> Tallies:
    from xray_viz.montecarlo.loop import run_batch
    from xray_viz.montecarlo.rng import batch_states

    p = problem
    t = Tallies.zeros(p["n_regions"], p["shape"])
    state = batch_states(p["seed"], 1, first=index)[0]
    b = p["bvh"]
    tb = p["tables"]
    run_batch(n_hist, state, p["field"], p["energies"], p["cdf"], p["world_lo"], p["world_hi"],
              b.lo, b.hi, b.child, b.start, b.count, b.v0, b.v1, b.v2, b.body, p["rank_order"],
              tb.mu, tb.ln_e0, tb.d_ln_e, tb.sf, tb.ff2_cum, tb.dx,
              t.dep, t.img, t.img_sq, t.totals)
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


def _mean_error(total, total_sq, n):
    mean = total / n
    var = np.maximum(total_sq / n - mean * mean, 0.0)
    return mean, np.sqrt(var / max(n - 1, 1))


@dataclass
class Transport:
    """The result of :func:`xray_viz.transport`: energies in eV per history, with standard
    errors.

    Attributes
    ----------
    histories : int
        Photons emitted into the field.
    energy, energy_error : dict of str to float
        Energy deposited in each body's region (where it wins the precedence), eV per history.
    images, image_errors : dict of str to (H, W) float
        ``"primary"``, ``"incoherent"`` (one incoherent scattering), ``"coherent"`` (one
        coherent scattering), ``"multiple"``: the energy of the photons reaching each pixel,
        eV per history.
    balance : dict of str to float
        eV per history: ``emitted``, ``deposited`` (bodies), ``world`` (the world medium),
        ``escaped``, ``detector``; ``emitted`` = the others' sum, to rounding.
    dose, dose_error : dict of str to float or None
        Gy per body with ``[source] mas`` (its region's mass from volume and density).
    seed : int
    """

    histories: int
    energy: dict
    energy_error: dict
    images: dict
    image_errors: dict
    balance: dict
    dose: dict | None = None
    dose_error: dict | None = None
    seed: int = 0
    extra: dict = field(default_factory=dict)

    def table(self) -> list[dict]:
        """One row per body: name, eV per history, its standard error, Gy and its error."""
        rows = []
        for name in self.energy:
            rows.append({"body": name, "energy_eV_per_history": self.energy[name],
                         "energy_error": self.energy_error[name],
                         "dose_Gy": None if self.dose is None else self.dose[name],
                         "dose_error": None if self.dose is None else self.dose_error[name]})
        return rows


IMAGE_KEYS = ("primary", "incoherent", "coherent", "multiple")


def result(tallies: Tallies, *, histories: int, names, seed: int, masses=None,
           photons=None) -> Transport:
    """A :class:`Transport` from summed tallies (keV) of ``histories`` histories."""
    n = int(histories)
    ev = 1000.0
    mean, err = _mean_error(tallies.dep[0], tallies.dep[1], n)
    energy = {name: float(mean[1 + k] * ev) for k, name in enumerate(names)}
    energy_error = {name: float(err[1 + k] * ev) for k, name in enumerate(names)}
    im, ie = _mean_error(tallies.img, tallies.img_sq, n)
    images = {key: im[k] * ev for k, key in enumerate(IMAGE_KEYS)}
    image_errors = {key: ie[k] * ev for k, key in enumerate(IMAGE_KEYS)}
    tot = tallies.totals
    balance = {"emitted": tot[0] / n * ev, "deposited": float(tallies.dep[0, 1:].sum()) / n * ev,
               "world": tallies.dep[0, 0] / n * ev, "escaped": tot[3] / n * ev,
               "detector": tot[1] / n * ev}
    dose = dose_error = None
    if masses is not None and photons is not None:
        joule = 1.602176634e-19 * photons
        dose = {nm: energy[nm] * joule / masses[k] for k, nm in enumerate(names)}
        dose_error = {nm: energy_error[nm] * joule / masses[k] for k, nm in enumerate(names)}
    return Transport(histories=n, energy=energy, energy_error=energy_error, images=images,
                     image_errors=image_errors, balance={k: float(v) for k, v in balance.items()},
                     dose=dose, dose_error=dose_error, seed=seed)
