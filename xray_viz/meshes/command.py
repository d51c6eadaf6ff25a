"""``xray-viz mesh IN -o OUT [--units U] [--decimate FACES | --max-error MM]``: repair, decimate.

The command line (:mod:`xray_viz.cli`) registers it with :func:`add_mesh_parser`; the work is
done by :func:`mesh_command`, which returns the exit status.

Examples
--------
>>> import argparse
>>> parser = argparse.ArgumentParser(prog="xray-viz")
>>> sub = parser.add_subparsers(dest="command")
>>> add_mesh_parser(sub)  # doctest: +ELLIPSIS
ArgumentParser(prog='xray-viz mesh', ...)
>>> args = parser.parse_args(["mesh", "in.stl", "-o", "out.ply", "--decimate", "5000"])
>>> args.func is mesh_command, args.decimate, args.units
(True, 5000, 'mm')
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from xray_viz.errors import MeshError, SceneFileNotFoundError

__all__ = ["mesh_command", "volume_mesh_command", "add_mesh_parser", "WRITE_SUFFIXES",
           "VOLUME_TOLERANCE", "union_volume", "overlapping_pieces", "UNION_RAYS"]

#: Output formats written by ``xray-viz mesh`` (binary STL, binary PLY, OBJ, OFF).
WRITE_SUFFIXES = (".stl", ".ply", ".obj", ".off")

#: Relative change of the enclosed volume by decimation above which the report warns.
VOLUME_TOLERANCE = 0.03
#: More distinct labels than this in a "label map" is an image's grey values (a CT without
#: --ct), not an atlas's structures (the largest atlases label a few hundred).
MAX_LABELS = 1000

_DESCRIPTION = """\
Repair a triangle mesh so that it can be traced, optionally decimate it, and write it.

Repair always runs (pymeshlab): duplicate vertices are merged, and vertices on open edges
closer than 0.01 % of the bounding box diagonal; duplicate and zero-area faces and
unreferenced vertices removed, non-manifold edges and vertices split, small open stray pieces
removed (closed pieces are kept, however small), holes closed, faces oriented coherently and
inside-out pieces turned outward (a piece facing inward inside an outward one is a cavity and
is kept).

Decimation (quadric edge collapse, keeping the mesh closed) is either to a face count
(--decimate FACES) or to an error budget (--max-error MM: the fewest faces whose Hausdorff
distance to the repaired mesh stays within MM millimetres). A note follows the report when
the face count asked for could not be reached (the collapse keeps the mesh closed and its
topology) or the enclosed volume changed by more than 3 %.

Units: IN is read in --units (default mm, as in a scene file's body "units" key); the report's
volumes, the Hausdorff distance and --max-error are in mm whatever the unit, and OUT is
written in the same unit as IN, so that it can replace IN in a scene file unchanged.

A report of the mesh before and after is printed; its "input" column is the file as stored
(an STL keeps every triangle's corners separately, so its duplicate vertices show there and
their merging is listed among the changes). OUT is written atomically (a temporary
file in the same folder, then renamed), in the format given by its extension.
"""

_EPILOG = """\
input formats: .stl .obj .ply .off .glb .gltf .vtp .vtk
output formats: .stl (binary) .ply (binary) .obj .off

volumes: IN may be a label map (.nii .nii.gz .nrrd .nhdr .mha .mhd) or, with --ct, a CT in HU
(the same formats or a folder holding a DICOM series). OUT is then a folder: one closed
binary STL per label (in mm, the volume's RAS+ world coordinates) and NAME.toml, the [[body]]
tables to paste into a scene (set each body's material there). Surfaces are smoothed
(windowed sinc, within half a voxel diagonal of the voxel surface) and decimated within
--max-error MM of the smoothed surface (default: a quarter of the smallest voxel spacing);
each body's Hausdorff distance to its voxel surface is reported.

examples:
  xray-viz mesh scan.stl -o scan_fixed.stl
  xray-viz mesh skull.ply -o skull_50k.ply --decimate 50000
  xray-viz mesh frog.vtp -o frog.stl --max-error 0.2
  xray-viz mesh part_in_metres.stl -o part_fixed.stl --units m --max-error 0.05
  xray-viz mesh seg.nii.gz -o bodies/ --max-error 0.2
  xray-viz mesh ct_series/ --ct -o bodies/
"""


def add_mesh_parser(subparsers) -> argparse.ArgumentParser:
    """Register the ``mesh`` subcommand on an ``argparse`` subparsers object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers()`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The subcommand's parser, with ``func=mesh_command`` set as a default.
    """
    p = subparsers.add_parser(
        "mesh", help="repair (and optionally decimate) a mesh file",
        description=_DESCRIPTION, epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", metavar="IN", help="mesh file to read")
    from xray_viz.scene import LENGTH_UNITS

    p.add_argument("-o", "--output", metavar="OUT", required=True,
                   help="mesh file to write (.stl, .ply, .obj or .off), in the unit of IN; for "
                        "a volume IN, a folder for its meshes and scene snippet")
    p.add_argument("--units", choices=tuple(LENGTH_UNITS), default="mm",
                   help="length unit of IN's coordinates (default: mm); the report and "
                        "--max-error are in mm, OUT keeps IN's unit")
    group = p.add_mutually_exclusive_group()
    group.add_argument("--decimate", metavar="FACES", type=int, default=None,
                       help="decimate to this many triangles")
    group.add_argument("--max-error", metavar="MM", type=float, default=None,
                       help="decimate as far as the Hausdorff distance stays within MM mm")
    p.add_argument("--ct", action="store_true",
                   help="IN is a CT in Hounsfield units (NIfTI, NRRD/MHA or a DICOM series "
                        "folder): segment it by the default HU table (after Schneider et al. "
                        "2000) before meshing")
    p.set_defaults(func=mesh_command)
    return p


def _check_output(out: Path) -> Path:
    """OUT's folder, after checking that OUT can be written: a known suffix (in any case), an
    existing folder, not a folder itself, not read-only (:func:`xray_viz.output.check_target`)."""
    from xray_viz.output import check_target

    if out.suffix.lower() not in WRITE_SUFFIXES:
        raise MeshError(f"{out}: cannot write {out.suffix or 'files without an extension'!r}; "
                        f"use one of {', '.join(WRITE_SUFFIXES)}")
    folder = out.parent if str(out.parent) else Path(".")
    if not folder.is_dir():
        raise SceneFileNotFoundError(f"{out}: folder {folder} does not exist; create it first")
    if out.is_dir():
        raise MeshError(f"{out}: is a folder; give a file name to write")
    check_target(out)
    return folder


def _check_written_mesh(tmp: str, mesh, file_type: str) -> None:
    """Read a written mesh back (trimesh) and compare its triangle count with ``mesh``'s."""
    import trimesh

    back = trimesh.load(tmp, file_type=file_type, force="mesh", process=False)
    n = len(getattr(back, "faces", ()))
    if n != len(mesh.faces):
        raise MeshError(f"it holds {n} triangles, not {len(mesh.faces)}")


def _write_atomic(mesh, out: Path) -> None:
    """Write ``mesh`` to OUT through :func:`xray_viz.output.atomic_write`: a temporary file,
    read back and checked, renamed into place (the previous OUT is kept on any failure)."""
    from xray_viz.output import atomic_write

    _check_output(out)
    file_type = out.suffix.lower()[1:]
    def write(tmp):
        with open(tmp, "wb") as fh:   # closed on a failed write too (trimesh's own is not)
            mesh.export(fh, file_type=file_type)

    atomic_write(out, write, verify=lambda tmp: _check_written_mesh(tmp, mesh, file_type))


def mesh_command(args, *, stdout=None) -> int:
    """Run ``xray-viz mesh``: repair, optionally decimate, report, write.

    Parameters
    ----------
    args : argparse.Namespace
        ``input``, ``output``, ``decimate`` (int or None), ``max_error`` (float or None, mm),
        ``units`` (a key of :data:`xray_viz.scene.LENGTH_UNITS`, default ``"mm"``: the unit of
        IN's coordinates; OUT is written in the same unit).
    stdout : file, optional
        Where the report goes (default ``sys.stdout``).

    Returns
    -------
    int
        0 on success.

    Raises
    ------
    SceneFileNotFoundError
        IN does not exist, or OUT's folder does not.
    MeshError
        IN cannot be read, repair fails, decimation opens the mesh, or OUT's format is not
        supported.
    """
    from xray_viz.meshes.decimate import decimate
    from xray_viz.meshes.io import load_mesh
    from xray_viz.meshes.repair import check_mesh, format_reports, repair_mesh
    from xray_viz.scene import LENGTH_UNITS

    out = sys.stdout if stdout is None else stdout
    src, dst = Path(args.input), Path(args.output)
    from xray_viz.meshes.volumes import is_volume_path

    if is_volume_path(src) or getattr(args, "ct", False):
        return volume_mesh_command(args, stdout=out)
    target = getattr(args, "decimate", None)
    max_error = getattr(args, "max_error", None)
    units = getattr(args, "units", None) or "mm"
    if units not in LENGTH_UNITS:
        raise MeshError(f"--units must be one of {', '.join(LENGTH_UNITS)}, got {units!r}")
    scale = LENGTH_UNITS[units]  # mm per unit of the file
    if target is not None and max_error is not None:
        raise MeshError("give --decimate or --max-error, not both")
    if target is not None and target < 4:
        raise MeshError(f"--decimate must be at least 4 faces, got {target}")
    if max_error is not None and not max_error > 0:
        raise MeshError(f"--max-error must be > 0 mm, got {max_error}")
    _check_output(dst)  # before the work: a bad OUT fails at once, not after the repair

    mesh = load_mesh(src, process=False)  # as stored: the report's input column is the file
    if scale != 1.0:
        mesh.apply_scale(scale)           # work in mm: the report, Hausdorff and --max-error
    repaired, report = repair_mesh(mesh)
    if not report.after.traceable:
        print(report.table(), file=out)
        raise MeshError(f"{src}: repair failed: the mesh is still "
                        f"{'; '.join(report.after.problems())}; close it in a mesh editor")
    overlap = overlapping_pieces(repaired, report.after)
    shown = report.after
    if overlap is not None:         # the table says what the render sees: the union
        crossing, union, summed = overlap
        shown = dataclasses.replace(report.after, volume=union, self_intersections=(
            (report.after.self_intersections or 0) + crossing))
    columns = [("input", report.before), ("repaired", shown)]
    changes = list(report.changes)
    notes = []
    if overlap is not None:
        notes.append(f"{report.after.components} pieces overlap ({crossing} faces cross "
                     f"another piece's): the render fills their union, {union:.6g} mm^3 "
                     f"(the pieces' volumes add up to {summed:.6g} mm^3); the self-"
                     "intersecting faces counted include those crossings")
    result = repaired
    if target is not None or max_error is not None:
        result, error = decimate(repaired, target_faces=target, max_error=max_error)
        after = check_mesh(result)
        columns.append(("decimated", after))
        if result is repaired:
            changes.append(f"not decimated: the repaired mesh has {len(repaired.faces)} faces"
                           + (f", no more than {target}" if target is not None else
                              f", and fewer would exceed {max_error:g} mm"))
        else:
            changes.append(f"decimated {len(repaired.faces)} -> {len(result.faces)} faces, "
                           f"Hausdorff distance {error:.4g} mm")
        notes += _decimation_notes(target, repaired, result, report.after.volume,
                                   after.volume)
    print(f"{src} -> {dst}" + (f" (coordinates in {units}; the report in mm)"
                               if units != "mm" else ""), file=out)
    print(format_reports(columns, changes=changes), file=out)
    for note in notes:
        print(f"note: {note}", file=out)
    if scale != 1.0:
        result = result.copy()
        result.apply_scale(1.0 / scale)   # back to the unit of IN
    _write_atomic(result, dst)
    return 0


def _decimation_notes(target, repaired, result, volume_before, volume_after) -> list[str]:
    """What the report should point out about a decimation: the face count asked for was not
    reached, or the enclosed volume changed by more than :data:`VOLUME_TOLERANCE`."""
    notes = []
    n = len(result.faces)
    if target is not None and abs(n - target) > max(2, target // 100) and result is not repaired:
        notes.append(f"asked for {target} faces, got {n}: quadric edge collapse keeps the mesh "
                     "closed and its topology (holes, pieces), so it stops where a further "
                     "collapse would break them")
    if volume_before and result is not repaired:
        change = volume_after / volume_before - 1.0
        if abs(change) > VOLUME_TOLERANCE:
            notes.append(f"the enclosed volume changed by {100 * change:+.0f} % "
                         f"({volume_before:.6g} -> {volume_after:.6g} mm^3): too few faces for "
                         "this shape; ask for more faces or use --max-error")
    return notes


#: Material written for a label into the scene snippet of ``xray-viz mesh VOLUME``: a
#: placeholder for the user to edit.
PLACEHOLDER_MATERIAL = "Tissue, Soft (ICRP)"


def volume_mesh_command(args, *, stdout=None) -> int:
    """Run ``xray-viz mesh VOLUME -o FOLDER``: one STL per label and a scene snippet.

    Parameters
    ----------
    args : argparse.Namespace
        ``input`` (a label map, or with ``ct`` a CT), ``output`` (a folder; made if missing,
        its parent must exist), ``max_error`` (mm or None), ``ct`` (bool).
    stdout : file, optional
        Where the report goes.

    Returns
    -------
    int
        0 on success. Nothing is written when anything fails.
    """
    from xray_viz.meshes import volumes as vol
    from xray_viz.output import atomic_write

    out = sys.stdout if stdout is None else stdout
    src, dst = Path(args.input), Path(args.output)
    if getattr(args, "decimate", None) is not None:
        raise MeshError(f"{src}: --decimate does not apply to a volume; use --max-error MM")
    if (getattr(args, "units", None) or "mm") != "mm":
        raise MeshError(f"{src}: --units does not apply to a volume: its affine gives mm")
    max_error = getattr(args, "max_error", None)
    if max_error is not None and not max_error > 0:
        raise MeshError(f"--max-error must be > 0 mm, got {max_error}")
    if dst.exists() and not dst.is_dir():
        raise MeshError(f"{dst}: is a file; for a volume, -o names a folder for the meshes")
    parent = dst.parent if str(dst.parent) else Path(".")
    if not parent.is_dir():
        raise SceneFileNotFoundError(f"{dst}: folder {parent} does not exist; create it first")
    if not src.exists():
        raise SceneFileNotFoundError(f"{src}: volume file not found")
    ct = bool(getattr(args, "ct", False))
    if ct:
        result = vol.ct_surfaces(src, max_error=max_error)
        materials = {k: (m, d) for k, (_, _, _, m, d) in enumerate(vol.SCHNEIDER_2000, start=1)}
    else:
        labels = [int(v) for v in np.unique(vol.read_volume(src).data) if v != 0]
        if not labels:
            raise MeshError(f"{src}: no labels (every voxel is 0, the background)")
        if len(labels) > MAX_LABELS:         # a CT's grey values, not an atlas's structures
            raise MeshError(f"{src}: {len(labels)} different labels: this looks like an image "
                            "(a CT), not a label map; mesh a CT with --ct")
        result = vol.label_surfaces(src, labels, max_error=max_error)
        materials = {}
    stem = vol._stem(src)
    lines = [f"# [[body]] tables for {src.name}, made by `xray-viz mesh` (max_error "
             f"{result.max_error:g} mm; RAS+ world coordinates in mm).",
             "# Paste them into a scene file (mesh paths are relative to this file's folder)"
             + ("." if ct else " and set each body's material: the placeholder is soft tissue.")]
    rows = [("body", "label", "voxels", "faces", "Hausdorff mm")]
    for s in result.surfaces:
        material, density = materials.get(s.label, (PLACEHOLDER_MATERIAL, None))
        what = f"HU class {s.label}" if ct else f"label {s.label}"
        lines += ["", "[[body]]", f'name = "{s.name}"', f'mesh = "{s.name}.stl"',
                  f'material = "{material}"' + ("" if ct else f"   # {what}: edit")]
        if density is not None:
            lines.append(f"density = {density:g}")
        rows.append((s.name, str(s.label), str(s.voxels), str(len(s.mesh.faces)),
                     f"{s.hausdorff:.3g}"))
    dst.mkdir(exist_ok=True)
    for s in result.surfaces:
        _write_atomic(s.mesh, dst / f"{s.name}.stl")
    snippet = "\n".join(lines) + "\n"
    atomic_write(dst / f"{stem}.toml", lambda tmp: Path(tmp).write_text(snippet))
    widths = [max(len(r[k]) for r in rows) for k in range(len(rows[0]))]
    print(f"{src} -> {dst}/ ({len(result.surfaces)} bodies"
          + (", from the cache" if result.cache_hit else "") + ")", file=out)
    for r in rows:
        print("  " + "  ".join(c.rjust(w) if k else c.ljust(w)
                               for k, (c, w) in enumerate(zip(r, widths))), file=out)
    if result.skipped:
        print(f"note: labels {', '.join(map(str, result.skipped))} skipped", file=out)
    print(f"wrote {len(result.surfaces)} meshes and {dst / (stem + '.toml')}", file=out)
    return 0


#: Rays across the bounding box, each way, of :func:`union_volume`.
UNION_RAYS = 400


def union_volume(mesh, *, rays: int = UNION_RAYS) -> float:
    """The volume (mm^3) of the region a closed mesh's surface winds around at least once
    (the nonzero rule: overlapping pieces count once), as every engine fills it.

    Parallel rays along -z through the centres of a ``rays`` x ``rays`` grid over the mesh's
    bounding box, each ray's length inside by the winding of its watertight hits (the
    midpoint rule: exact for faces along the grid's cells, else within about a cell's width
    times the outline).

    Examples
    --------
    >>> import trimesh
    >>> a = trimesh.creation.box(extents=[2, 2, 2])
    >>> b = a.copy(); _ = b.apply_translation([1, 0.5, 0.25])
    >>> both = trimesh.util.concatenate([a, b])
    >>> round(float(union_volume(both, rays=480)), 6), round(float(both.volume), 6)  # 16 - 2.625
    (13.375, 16.0)
    """
    from xray_viz.tracing.hits import trace_triangles

    lo, hi = np.asarray(mesh.bounds, dtype=np.float64)
    size = np.maximum(hi - lo, 1e-12)
    u = lo[0] + (np.arange(rays) + 0.5) * size[0] / rays
    v = lo[1] + (np.arange(rays) + 0.5) * size[1] / rays
    x, y = np.meshgrid(u, v, indexing="ij")
    origins = np.column_stack([x.ravel(), y.ravel(), np.full(x.size, hi[2] + 1.0)])
    down = np.array([0.0, 0.0, -1.0])
    ray, _, t, _, entering = trace_triangles(np.asarray(mesh.triangles), origins, down,
                                             axis=down)
    if len(t) == 0:
        return 0.0
    winding = np.cumsum(np.where(entering, 1, -1))   # 0 again after each ray's last hit
    inside = (winding[:-1] > 0) & (ray[1:] == ray[:-1])
    length = float(np.sum((t[1:] - t[:-1])[inside]))
    return length * (size[0] / rays) * (size[1] / rays)


def overlapping_pieces(mesh, report) -> tuple[int, float, float] | None:
    """``(faces crossing a face of another piece, union volume, summed volume)`` of a closed,
    outward mesh of several pieces some of which cross each other; None otherwise (one
    piece, pieces apart or nested). The render fills the union (:func:`union_volume`)."""
    from xray_viz.meshes.repair import self_intersecting_faces

    if report.components < 2 or not report.traceable:
        return None
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    crossing = int(self_intersecting_faces(vertices, faces).sum()) - (
        report.self_intersections or 0)
    if crossing <= 0:
        return None
    return crossing, union_volume(mesh), float(report.volume)
