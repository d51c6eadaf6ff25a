"""``xray-viz convert``: a gVirtualXray JSON scene written as an xray-viz TOML scene file.

The conversion itself is :func:`xray_viz.meshes.gvxr.gvxr_to_dict`; this command checks the
result by building the scene (every mesh and value), rewrites mesh paths relative to the
output's folder, and writes the file atomically, verified by reading it back.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from xray_viz.errors import SceneError, SceneFileNotFoundError
from xray_viz.meshes.gvxr import gvxr_to_dict, read_json, to_toml

__all__ = ["add_convert_parser", "convert_command"]


def add_convert_parser(subparsers):
    """Register ``xray-viz convert IN.json -o OUT.toml``."""
    import argparse

    p = subparsers.add_parser(
        "convert", help="convert a gVirtualXray JSON scene to a TOML scene file",
        description="Convert a gVirtualXray (gVXR) JSON scene file to an xray-viz TOML scene "
                    "file. Mesh paths are rewritten relative to OUT's folder. What has no "
                    "equivalent is an error naming the gVXR key (see the README, 'Volumes and "
                    "other scene formats').",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", metavar="IN", help="a gVXR .json scene file")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="the .toml to write")
    p.set_defaults(func=convert_command)
    return p


def convert_command(args, *, stdout=None) -> int:
    """Run ``xray-viz convert``: read, check (the scene is built), write atomically."""
    import sys
    import tomllib

    from xray_viz.output import atomic_write, check_target
    from xray_viz.scene import scene_from_dict

    out = sys.stdout if stdout is None else stdout
    src, dst = Path(args.input), Path(args.output)
    if dst.suffix.lower() != ".toml":
        raise SceneError(f"{dst}: convert writes a TOML scene file; name it .toml")
    folder = dst.parent if str(dst.parent) else Path(".")
    if not folder.is_dir():
        raise SceneFileNotFoundError(f"{dst}: folder {folder} does not exist; create it first")
    check_target(dst)
    doc = gvxr_to_dict(read_json(src), base_dir=src.parent, file=src)
    scene = scene_from_dict(doc, base_dir=src.parent, file=src)   # every mesh and value checked
    for body in doc["body"]:
        mesh = Path(body["mesh"])
        full = mesh if mesh.is_absolute() else (src.parent / mesh).resolve()
        try:
            body["mesh"] = Path(os.path.relpath(full, folder.resolve())).as_posix()
        except ValueError:   # another drive
            body["mesh"] = str(full)
    text = to_toml(doc, header=f"Converted from the gVirtualXray scene {src.name} by "
                               "`xray-viz convert`.")

    def verify(tmp):
        if tomllib.loads(Path(tmp).read_text(encoding="utf-8")) != json.loads(json.dumps(doc)):
            raise SceneError("the TOML written does not read back as the scene")

    atomic_write(dst, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), verify=verify)
    n = len(scene.bodies)
    print(f"wrote {dst} ({n} bod{'y' if n == 1 else 'ies'}) from {src}", file=out)
    return 0
