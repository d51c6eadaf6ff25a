"""How the scene view looks: colours, the material palette, line widths, opacities, font sizes.

Every constant the 3D scene and the radiograph pane of :class:`~xray_viz.viz.SceneView` draw
with, in one place; :mod:`xray_viz.viz.shapes` builds the geometry, this module says how it is
painted. The walkthroughs use the same colours where they draw the same things.

Examples
--------
>>> from xray_viz.viz.style import COLORS, PALETTE, material_color
>>> COLORS["source"]
'gold'
>>> material_color(0) == PALETTE[0] and material_color(len(PALETTE)) == PALETTE[0]
True
"""

from __future__ import annotations

__all__ = ["COLORS", "PALETTE", "ARROW_WIDTH", "CORNER_FONT", "LINE_WIDTHS", "OPACITY",
           "FONT_SIZES", "BODY_SPECULAR", "LEGEND", "material_color"]

#: Colours of what the viewer marks: the source, rays, hits, the picked ray and the HO, VE,
#: FL and LHC arrows. None of them is a material colour (:data:`PALETTE`), so a marker never
#: reads as a material: yellow for the source and rays, black for the ray inside the bodies,
#: bright green and sky blue for the entry and exit glyphs, magenta for the picked ray, red
#: and green (darker) for the viewport edges HO and VE, black and grey for FL and LHC.
COLORS = {
    "source": "gold",
    "detector": "#9aa4b1",
    "grid": "#303841",
    "ray": "#e0c000",
    "inside": "#1a1a1a",
    "entry": "#00d000",
    "exit": "#00b0ff",
    "picked": "magenta",
    "frustum": "#888888",
    "HO": "#e00000",
    "VE": "#008f00",
    "FL": "#1a1a1a",
    "LHC": "#7f7f7f",
}

#: Colours given to materials in order of appearance: matplotlib's tab10 and tab20b without
#: the reds, greens, cyans, yellows, greys and magentas of :data:`COLORS`.
PALETTE = ("#1f77b4", "#ff7f0e", "#9467bd", "#8c564b", "#393b79", "#e7969c", "#c49c94",
           "#6b6ecf", "#7b4173")

#: Width in pixels of the HO, VE, FL and LHC arrows' shafts.
ARROW_WIDTH = 3

#: Font size of the radiograph's corner labels, (0, 0) and (W - 1, H - 1).
CORNER_FONT = 14

#: Line widths in pixels: the traced rays, the picked ray, the pixel grid, the beam's frustum,
#: the outline of the picked pixel and the frame around the radiograph. The part of a ray
#: inside a body is drawn ``inside_extra`` wider than the ray.
LINE_WIDTHS = {"ray": 1, "picked": 3, "inside_extra": 1, "grid": 1, "frustum": 1,
               "picked_pixel": 3, "image_frame": 1}

#: Opacities: the bodies (translucent, so rays and nested bodies show through), the detector
#: plane without its texture, the part of a ray inside a body (the body's colour shows through
#: it), the pixel grid when it has many lines (``grid_dense``, more than
#: ``grid_dense_lines`` columns) or few, and the labels' background boxes.
OPACITY = {"body": 0.35, "detector": 0.45, "inside": 0.55, "grid_dense": 0.7, "grid": 1.0,
           "grid_dense_lines": 12, "label_box": 0.6, "legend": 0.7}

#: Specular reflection of the bodies' surfaces (smooth-shaded).
BODY_SPECULAR = 0.3

#: Font sizes (points): the HO/VE/FL/LHC labels (bold), the pixel grid's caption, the
#: radiograph's title lines, the viewer's key help, the colour bar's title and tick labels.
FONT_SIZES = {"vector_label": 12, "grid_label": 8, "image_title": 8, "help": 8,
              "colorbar_title": 12, "colorbar_labels": 11, "text": 9}

#: The legend of the 3D pane: background colour, placement, and the height of one entry as a
#: fraction of the pane (the legend is at most ``max_height`` high, ``width`` wide).
LEGEND = {"bcolor": "white", "loc": "upper left", "face": "rectangle", "width": 0.28,
          "entry_height": 0.026, "max_height": 0.3}


def material_color(k: int) -> str:
    """The colour of the ``k``-th material of a scene (in order of appearance, from 0),
    :data:`PALETTE` repeated.

    Examples
    --------
    >>> material_color(1)
    '#ff7f0e'
    """
    return PALETTE[int(k) % len(PALETTE)]
