"""The photon transport's results in a window (issue 38): the four detector images and the
energy (and dose) per body as a table.

:func:`plot_transport` draws a :class:`xray_viz.transport.Transport` into a PyVista plotter of
2 x 3 panes: the primary, single incoherent, single coherent and multiple-scatter images (eV
per history per pixel, each in its own colour range), the per-body table
(:func:`transport_table_text`: eV per history with its standard error, and Gy with its error
when the scene has ``[source] mas``) and the energy balance. ``xray-viz show SCENE --dose N``
runs :func:`xray_viz.transport` with ``N`` histories and opens it (or saves it with
``--screenshot``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["plot_transport", "transport_table_text", "IMAGE_TITLES", "TransportView"]

#: The four images' panes and titles, in the order of :data:`xray_viz.transport.IMAGE_KEYS`.
IMAGE_TITLES = {
    "primary": "primary (no interaction)",
    "incoherent": "single incoherent",
    "coherent": "single coherent",
    "multiple": "multiple scattering",
}


@dataclass
class TransportView:
    """What :func:`plot_transport` drew.

    Attributes
    ----------
    plotter : pyvista.Plotter
    grids : dict of str to pyvista.ImageData
        The four images as drawn.
    table : str
        The text of the per-body table.
    """

    plotter: object
    grids: dict
    table: str


def _g(value: float, error: float) -> str:
    """``value +- error`` with the error's two significant digits setting the precision.

    Examples
    --------
    >>> _g(123.456, 1.234)
    '123.5 +- 1.2'
    >>> _g(0.0, 0.0)
    '0 +- 0'
    """
    if not error or not np.isfinite(error):
        return f"{value:.4g} +- {error:.2g}"
    digits = max(0, 1 - int(np.floor(np.log10(abs(error)))))
    return f"{value:.{digits}f} +- {error:.{digits}f}"


def transport_table_text(result) -> str:
    """The per-body table of a transport as fixed-width text: body, eV per history and its
    standard error, and Gy and its error when the transport has doses.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> t = SimpleNamespace(histories=1000, energy={"water": 12.345}, dose=None,
    ...                     energy_error={"water": 0.678}, dose_error=None)
    >>> print(transport_table_text(t))
    body    eV/history (1000 histories)
    water   12.35 +- 0.68
    """
    names = list(result.energy)
    width = max([len("body")] + [len(n) for n in names]) + 3
    head = f"{'body':<{width}}eV/history ({result.histories} histories)"
    lines = []
    cells = [_g(result.energy[n], result.energy_error[n]) for n in names]
    if result.dose is not None:
        cw = max([len(c) for c in cells] + [len(f"eV/history ({result.histories} histories)")])
        head = f"{'body':<{width}}{'eV/history (' + str(result.histories) + ' histories)':<{cw + 3}}Gy"
        for n, c in zip(names, cells):
            lines.append(f"{n:<{width}}{c:<{cw + 3}}"
                         f"{result.dose[n]:.3e} +- {result.dose_error[n]:.1e}")
    else:
        lines = [f"{n:<{width}}{c}" for n, c in zip(names, cells)]
    return "\n".join([head] + lines)


def _balance_text(result) -> str:
    b = getattr(result, "balance", None) or {}
    order = ("emitted", "deposited", "world", "escaped", "detector")
    rows = [f"{k:<11}{b[k]:.6g}" for k in order if k in b]
    return "energy balance, eV/history\n" + "\n".join(rows)


def plot_transport(result, *, plotter=None, window_size=(1500, 900), off_screen=None,
                   title: str | None = None):
    """Draw a transport's four detector images and its per-body table.

    Parameters
    ----------
    result : Transport
        From :func:`xray_viz.transport`.
    plotter : pyvista.Plotter, optional
        A plotter of shape (2, 3) to draw into; by default a new one.
    window_size : (int, int)
    off_screen : bool, optional
        For a new plotter; default ``pyvista.OFF_SCREEN``.
    title : str, optional
        Put above the table (the scene's name, say).

    Returns
    -------
    TransportView
        Its plotter's panes (0, 0), (0, 1), (1, 0), (1, 1): the images of
        :data:`IMAGE_TITLES` (``grids[key]``: eV per history per pixel, row 0 of the array at
        the top); (0, 2): the table (``table``); (1, 2): the energy balance.
    """
    import pyvista as pv

    from xray_viz.transport import IMAGE_KEYS
    from xray_viz.viz.scene_view import image_to_grid

    if plotter is None:
        kw = {} if off_screen is None else {"off_screen": off_screen}
        plotter = pv.Plotter(shape=(2, 3), window_size=list(window_size), border=False, **kw)
    plotter.set_background("white")
    grids = {}
    panes = [(0, 0), (0, 1), (1, 0), (1, 1)]
    for key, (r, c) in zip(IMAGE_KEYS, panes):
        plotter.subplot(r, c)
        image = np.asarray(result.images[key], dtype=np.float64)
        name = f"{key} eV/history"
        grid = image_to_grid(image, name=name)
        grids[key] = grid
        lo, hi = float(image.min()), float(image.max())
        if not hi > lo:
            hi = lo + 1e-30
        plotter.add_mesh(grid, scalars=name, cmap="gray", clim=(lo, hi), lighting=False,
                         show_scalar_bar=True, name=f"transport:{key}",
                         scalar_bar_args=dict(title=f"{key}: eV/history per pixel",
                                              vertical=False, position_x=0.15,
                                              position_y=0.03, width=0.7, height=0.07,
                                              fmt="%.2g", color="black", n_labels=3,
                                              title_font_size=12, label_font_size=10))
        total = float(image.sum())
        plotter.add_text(f"{IMAGE_TITLES[key]}\nsum {total:.4g} eV/history", font_size=10,
                         color="black", position="upper_left")
        plotter.view_xy()
        plotter.enable_parallel_projection()
        plotter.reset_camera()
        plotter.camera.zoom(0.75)             # room for the title above, the bar below
    plotter.subplot(0, 2)
    text = transport_table_text(result)
    if title:
        text = f"{title}\n\n{text}"
    plotter.add_text(text, font_size=10, color="black", position="upper_left",
                     font="courier", name="transport:table")
    plotter.subplot(1, 2)
    plotter.add_text(_balance_text(result), font_size=10, color="black",
                     position="upper_left", font="courier", name="transport:balance")
    return TransportView(plotter=plotter, grids=grids, table=text)
