"""``xray-viz dose``: the photon transport of a scene, its energy and dose per body."""

from __future__ import annotations

import json
import math
from pathlib import Path

from xray_viz.errors import SceneError

__all__ = ["add_dose_parser", "dose_command", "OUTPUTS"]

#: The table's formats, by suffix of ``-o``.
OUTPUTS = (".csv", ".json")


def add_dose_parser(subparsers) -> None:
    """Register ``xray-viz dose`` on an argparse sub-parser collection."""
    p = subparsers.add_parser(
        "dose", help="photon Monte Carlo: energy and dose per body, scatter at the detector",
        description="Transport photons from the scene's source through its bodies, its "
                    "voxel volumes ([[ct]] / [[labels]] traced as voxels: one row per class) "
                    "and its [world] medium, and print the energy deposited in each region, "
                    "eV per history with its standard error, and the dose in Gy when [source] "
                    "gives mas. The same --seed gives the same numbers on any --workers.")
    p.add_argument("scene", metavar="SCENE", help="a scene .toml file or a bundled phantom")
    p.add_argument("--histories", type=int, required=True, metavar="N",
                   help="photons emitted into the field the detector covers")
    p.add_argument("--seed", type=int, default=0, metavar="S")
    p.add_argument("--workers", type=int, default=1, metavar="K",
                   help="K > 1: a Dask LocalCluster of K worker processes on 127.0.0.1")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="an existing Dask scheduler, e.g. tcp://host:8786")
    p.add_argument("-o", "--output", default=None, metavar="OUT",
                   help="write the table: .csv (one row per body) or .json (with the energy "
                        "balance)")
    p.set_defaults(func=dose_command)


def _rows(result) -> list[dict]:
    return result.table()


def _write(out: Path, result) -> None:
    from xray_viz.output import atomic_write

    rows = _rows(result)
    if out.suffix.lower() == ".json":
        doc = {"histories": result.histories, "seed": result.seed,
               "interrupted": bool(result.extra.get("interrupted")), "unit": "eV per history",
               "bodies": rows, "balance": result.balance}
        text = json.dumps(doc, indent=1, allow_nan=False)
    else:
        lines = ["body,energy_eV_per_history,energy_error,dose_Gy,dose_error"]
        for r in rows:
            name = '"' + r["body"].replace('"', '""') + '"'
            cells = [r["energy_eV_per_history"], r["energy_error"], r["dose_Gy"],
                     r["dose_error"]]
            lines.append(",".join([name] + ["" if c is None else repr(float(c))
                                            for c in cells]))
        text = "\n".join(lines) + "\n"

    def write(tmp):
        Path(tmp).write_text(text, encoding="utf-8")

    def verify(tmp):
        if Path(tmp).read_text(encoding="utf-8") != text:
            raise ValueError("read back differently")

    atomic_write(out, write, verify=verify)


def dose_command(args) -> int:
    """``xray-viz dose``: see :func:`add_dose_parser`."""
    import contextlib

    from xray_viz import progress
    from xray_viz.scene_file import load_scene
    from xray_viz.transport import transport

    if args.histories <= 0:
        raise SceneError(f"--histories must be > 0, got {args.histories}")
    if args.seed < 0:
        raise SceneError(f"--seed must be >= 0, got {args.seed}")
    if args.workers < 1:
        raise SceneError(f"--workers must be >= 1, got {args.workers}")
    if args.workers > 1 and args.scheduler:
        raise SceneError("give --workers or --scheduler, not both")
    out = Path(args.output) if args.output else None
    if out is not None and out.suffix.lower() not in OUTPUTS:
        raise SceneError(f"-o {out}: end it in .csv or .json")
    scene = load_scene(args.scene)
    with contextlib.ExitStack() as stack:
        client = None
        if args.scheduler or args.workers > 1:
            from distributed import Client

            if args.scheduler:
                client = stack.enter_context(Client(args.scheduler))
            else:
                from xray_viz.scan import local_cluster

                cluster = stack.enter_context(local_cluster(args.workers))
                client = stack.enter_context(Client(cluster))
        task = stack.enter_context(progress.task("transport", total=args.histories,
                                                 unit="histories"))
        result = transport(scene, args.histories, seed=args.seed, client=client,
                           progress=lambda done, total: task.update_to(done, total),
                           interruptible=True)
    width = max([4] + [len(n) for n in result.energy])
    dose = result.dose is not None
    print(f"{'body':<{width}}  {'eV/history':>12}  {'error':>10}" + ("  dose (Gy)    error"
                                                                       if dose else ""))
    for r in result.table():
        line = (f"{r['body']:<{width}}  {r['energy_eV_per_history']:12.6g}  "
                f"{r['energy_error']:10.3g}")
        if dose:
            line += f"  {r['dose_Gy']:10.4g}  {r['dose_error']:8.2g}"
        print(line)
    b = result.balance
    print(f"{result.histories} histories (seed {result.seed}); eV per history: emitted "
          f"{b['emitted']:.6g} = deposited {b['deposited']:.6g} + world {b['world']:.6g} + "
          f"escaped {b['escaped']:.6g} + detector {b['detector']:.6g}")
    if out is not None:
        _write(out, result)
        print(f"wrote {out}")
    if result.extra.get("interrupted"):
        print(f"xray-viz: interrupted after {result.histories} of {args.histories} histories"
              + (f" ({out} holds them)" if out is not None else ""))
        return 130
    return 0 if all(math.isfinite(v) for v in result.energy.values()) else 1
