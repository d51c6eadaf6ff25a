"""``xray-viz convert``: a gVirtualXray JSON scene written as an xray-viz TOML scene file.

The conversion itself is :func:`xray_viz.meshes.gvxr.gvxr_to_dict`; this command checks the
result by building the scene (every mesh and value), rewrites mesh paths relative to the
output's folder, and writes the file atomically, verified by reading it back.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from xray_viz.errors import SceneError
from xray_viz.meshes.gvxr import gvxr_to_dict, read_json, to_toml

__all__ = ["add_convert_parser", "convert_command", "add_init_parser", "init_command"]


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

    from xray_viz.output import atomic_write, scene_target
    from xray_viz.scene_file import scene_from_dict

    out = sys.stdout if stdout is None else stdout
    src, dst = Path(args.input), scene_target(args.output, command="convert")
    folder = dst.parent
    doc = gvxr_to_dict(read_json(src), base_dir=src.parent, file=src)
    scene = scene_from_dict(doc, base_dir=src.parent, file=src)   # every mesh and value checked
    for body in doc["body"]:
        if "mesh" not in body:       # a primitive (a gVXR Cube): no file
            continue
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


def add_init_parser(subparsers):
    """Register ``xray-viz init [--from MESH] [-o OUT.toml]``."""
    import argparse

    p = subparsers.add_parser(
        "init", help="write a commented scene file to edit (framed around a mesh file)",
        description="Write a commented scene file to start from: a point source and a detector "
                    "framed around the mesh MESH (any mesh file xray-viz reads: STL, OBJ, PLY, "
                    "OFF, GLB, VTK), aluminium at 60 keV, the mesh read in mm. Without --from, "
                    "an example mesh (a washer, 50 mm across) is written beside OUT as "
                    "OUT-part.stl. Then: xray-viz render OUT -o image.png",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--from", dest="mesh", metavar="MESH", default=None,
                   help="the mesh file the scene frames (default: an example mesh)")
    p.add_argument("-o", "--output", default="scene.toml", metavar="OUT",
                   help="the .toml to write (default: %(default)s); an existing file is kept "
                        "unless --force")
    p.add_argument("--force", action="store_true", help="replace an existing OUT")
    p.set_defaults(func=init_command)
    return p


def init_command(args, *, stdout=None) -> int:
    """Run ``xray-viz init``: frame the mesh, check the scene loads, write it atomically."""
    import sys
    import tomllib

    from xray_viz.errors import XrayVizError
    from xray_viz.output import atomic_write, check_target, scene_target
    from xray_viz.scene_file import scene_from_dict
    from xray_viz.starter import is_mesh_file, scene_text

    out = sys.stdout if stdout is None else stdout
    dst = scene_target(args.output, command="init")
    folder = dst.parent
    targets = [dst]
    if args.mesh is None:
        mesh = folder / f"{dst.stem}-part.stl"
        targets.append(mesh)
    else:
        mesh = Path(args.mesh)
        if not is_mesh_file(mesh):
            raise SceneError(f"{mesh}: not a mesh file xray-viz reads (STL, OBJ, PLY, OFF, GLB, "
                             "VTK); for a gVirtualXray JSON scene use `xray-viz convert`")
    for target in targets:
        if target.exists() and not args.force:
            raise XrayVizError(f"{target}: exists; pass --force to replace it, or choose "
                               "another -o")
        check_target(target)
    if args.mesh is None:
        import trimesh

        washer = trimesh.creation.annulus(r_min=10.0, r_max=25.0, height=12.0, sections=96)
        washer.apply_transform(trimesh.transformations.rotation_matrix(1.0471975511965976, [1, 0, 0]))   # 60 deg
        atomic_write(mesh, lambda tmp: washer.export(tmp))
    text = scene_text(mesh, relative_to=folder, name=dst.name)
    doc = tomllib.loads(text)
    scene_from_dict(doc, base_dir=folder, file=dst)        # every mesh and value checked

    def verify(tmp):
        if tomllib.loads(Path(tmp).read_text(encoding="utf-8")) != doc:
            raise SceneError("the TOML written does not read back as the scene")

    atomic_write(dst, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), verify=verify)
    made = f" and {mesh}" if args.mesh is None else ""
    print(f"wrote {dst}{made}: edit it, then `xray-viz render {dst} -o image.png`", file=out)
    return 0
