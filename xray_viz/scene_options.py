"""What the commands share: the scene overrides (``--energy``, ``--shape``, ``--angle``, ...)
and the notice shown while kernels compile.

``xray-viz render`` and ``xray-viz show`` (:mod:`xray_viz.viz.command`) both take the overrides;
the walkthroughs show the compile notice. Kept apart from :mod:`xray_viz.cli`, which imports
every command, so that no command imports the command line back.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from xray_viz import progress
from xray_viz.errors import XrayVizError

__all__ = ["OVERRIDES", "add_scene_overrides", "load_scene_with_overrides", "turn_acquisition"]

log = logging.getLogger("xray_viz.cli")


def _compile_notice(engine: str):
    """A context in which numba's first compilation of a fast-engine kernel prints one line
    on stderr, saying where numba will cache the kernels (numba's own answer, see
    :mod:`xray_viz.tracing._numba_cache`). Kernels loaded from the cache are not compiled, so
    a warm cache prints nothing, wherever it is."""
    import contextlib

    from xray_viz.tracing.engines import ENGINES

    if engine not in ENGINES or not ENGINES[engine].compiled:
        return contextlib.nullcontext()
    from xray_viz.tracing import _numba_cache

    return _numba_cache.on_first_compile(_say_compiling)


def _say_compiling(where) -> None:
    """The compile notice, for kernels about to be cached in ``where`` (None: uncached).

    Said once per kernel cache (a marker file beside the kernels), not once per kind of
    scene: a new user's next scenes need a few other kernels, compiled as quietly as they
    load (the progress line on a terminal still says so), at debug level (``-v``).
    Uncached: said every time, since every process compiles again.
    """
    from xray_viz import __version__

    marker = Path(where) / f".compile-notice-{__version__}" if where else None
    seen = marker is not None and marker.exists()
    then = f"cached in {where} afterwards" if where else "not cached: no writable place"
    logging.getLogger("xray_viz.compile").log(
        logging.DEBUG if seen else logging.INFO,
        "compiling the fast engine on first use (a few seconds, %s)...", then)
    progress.status("compiling the fast engine")
    if marker is not None and not seen:
        try:
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.touch()
        except OSError:          # a cache numba writes but this user cannot: said again
            pass


# --------------------------------------------------------------------------------------------
# Scene overrides: the scene file's values changed for one run, checked like the file's keys

#: Each override: (option, what it sets in the scene file).
OVERRIDES = (
    ("--energy", "[source] energy"),
    ("--kvp", "[source] spectrum kvp"),
    ("--source-distance", "[source] position"),
    ("--shape", "[detector] shape"),
    ("--pitch", "[detector] pitch"),
    ("--detector-size", "[detector] size"),
    ("--noise", "[detector] noise"),
    ("--seed", "[detector] seed"),
)
# --angle turns the acquisition (source and detector together) about the bodies: no key of the
# scene file says that, so it is applied to the loaded scene (see turn_acquisition).


def add_scene_overrides(parser: argparse.ArgumentParser) -> None:
    """Add the options that change a scene file's values for one run (``render``, ``show``).

    Each one edits the parsed scene file before it is checked, so that it is checked exactly
    like the key it sets (see :func:`load_scene_with_overrides`).

    Examples
    --------
    >>> parser = argparse.ArgumentParser()
    >>> add_scene_overrides(parser)
    >>> parser.parse_args(["--kvp", "70", "--no-noise"]).noise
    False
    """
    g = parser.add_argument_group(
        "scene overrides",
        "Change the scene file's values for this run, without editing it. Each is checked like "
        "the key it sets in the file.")
    beam = g.add_mutually_exclusive_group()
    beam.add_argument("--energy", type=float, metavar="KEV",
                      help="[source] energy: a monochromatic beam of KEV keV (instead of the "
                           "file's energy or spectrum)")
    beam.add_argument("--kvp", type=float, metavar="KV",
                      help="[source] spectrum kvp: a tube spectrum at KV kVp (the file's other "
                           "spectrum keys kept; instead of a monochromatic energy)")
    g.add_argument("--source-distance", type=float, metavar="MM",
                   help="[source] position: move the source along the beam axis to MM from the "
                        "detector centre")
    g.add_argument("--shape", type=int, nargs=2, metavar=("W", "H"),
                   help="[detector] shape: W x H pixels (the file's pitch, or size, kept)")
    grid = g.add_mutually_exclusive_group()
    grid.add_argument("--pitch", type=float, nargs="+", metavar="MM",
                      help="[detector] pitch: mm between pixels, one number or two (along HO, "
                           "VE); instead of the file's pitch or size")
    grid.add_argument("--detector-size", type=float, nargs=2, metavar=("W", "H"),
                      help="[detector] size: [|HO|, |VE|] in mm; instead of the file's pitch or "
                           "size")
    g.add_argument("--noise", action=argparse.BooleanOptionalAction, default=None,
                   help="[detector] noise: Poisson noise on (needs the file's I0 or mas) or off")
    g.add_argument("--seed", type=int, metavar="N", help="[detector] seed of the noise")
    g.add_argument("--angle", type=float, metavar="DEG",
                   help="turn the source and the detector together DEG degrees about the "
                        "detector's up axis through the centre of the bodies (one view of a "
                        "CT orbit; the bodies and their set-up stay as they are)")


def _given_overrides(args) -> list[tuple[str, object]]:
    """``(option, value)`` of each override given on the command line."""
    given = []
    for option, _ in OVERRIDES:
        value = getattr(args, option[2:].replace("-", "_"), None)
        if value is not None:
            given.append((option, value))
    return given


def _shown_option(option, value) -> str:
    if option == "--noise":
        return "--noise" if value else "--no-noise"
    items = value if isinstance(value, list) else [value]
    return " ".join([option, *(f"{v:g}" if isinstance(v, float) else str(v) for v in items)])


def _apply_override(doc: dict, option: str, value) -> None:
    """Edit the parsed scene file ``doc`` as if its author had written ``value`` for the key
    that ``option`` sets. Values of the wrong kind in the file are left for its own checks."""
    src = doc.get("source") if isinstance(doc.get("source"), dict) else None
    det = doc.get("detector") if isinstance(doc.get("detector"), dict) else None
    if option == "--energy" and src is not None:
        src.pop("spectrum", None)
        src["energy"] = value
    elif option == "--kvp" and src is not None:
        spectrum = src.get("spectrum")
        src.pop("energy", None)
        src["spectrum"] = {**spectrum, "kvp": value} if isinstance(spectrum, dict) \
            else {"kvp": value}
    elif option == "--source-distance" and src is not None and det is not None:
        import math

        import numpy as np

        if not (math.isfinite(value) and value > 0):
            raise XrayVizError(f"{_shown_option(option, value)}: the source distance must be a "
                               "number > 0 (mm from the detector centre)")
        try:
            p = np.asarray(src["position"], dtype=np.float64).reshape(3)
            c = np.asarray(det["center"], dtype=np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            return                                    # the file's own check names it
        axis = p - c
        norm = float(np.linalg.norm(axis))
        if not (np.all(np.isfinite(axis)) and norm > 0):
            return
        src["position"] = (c + value * (axis / norm)).tolist()
    elif det is not None and option in ("--shape", "--pitch", "--detector-size"):
        if option == "--pitch" and len(value) not in (1, 2):
            raise XrayVizError(f"{_shown_option(option, value)}: give one number (mm) "
                               "or two (along HO and VE)")
        if option == "--shape":
            det["shape"] = list(value)
            return
        det.pop("pitch", None)
        det.pop("size", None)
        if option == "--pitch":
            det["pitch"] = value[0] if len(value) == 1 else list(value)
        else:
            det["size"] = list(value)
    elif det is not None and option in ("--noise", "--seed"):
        det[option[2:]] = value


def _scene_file(name) -> Path:
    """The scene file that :func:`xray_viz.load_scene` reads for ``name`` (a file or a
    bundled phantom); its error when there is none."""
    import xray_viz
    from xray_viz import phantoms

    p = Path(name)
    if p.is_file():
        return p
    bare = not p.suffix and "/" not in str(name) and "\\" not in str(name)
    resolved = phantoms.scene_path(str(name)) if bare else None
    if resolved is not None:
        return Path(resolved)
    return xray_viz.load_scene(name).path          # raises load_scene's own error


def _parse(doc, path):
    from xray_viz.scene_file import scene_from_dict

    return scene_from_dict(doc, base_dir=path.parent, file=path)


def turn_acquisition(scene, angle):
    """The scene seen from its source and detector turned ``angle`` degrees about the
    detector's up axis through the centre of the bodies' bounding box (the detector centre
    when there are no bodies): ``--angle``.

    Raises
    ------
    XrayVizError
        ``angle`` is not a finite number.

    Examples
    --------
    >>> import xray_viz
    >>> scene = turn_acquisition(xray_viz.load_scene("sphere"), 90.0)
    >>> (scene.source.position.round(6) + 0.0).tolist()
    [1000.0, 0.0, 0.0]
    """
    import math

    import numpy as np

    if not math.isfinite(angle):
        raise XrayVizError(f"--angle {angle}: give a finite number of degrees")
    from xray_viz.volume import imaged_centre

    centre = imaged_centre(scene)          # the bodies' and the voxel volumes' box
    if centre is None:
        centre = np.asarray(scene.detector.center)
    return scene.replace(acquisition=scene.acquisition.rotated(
        angle, axis=scene.detector.up, center=centre))


def load_scene_with_overrides(args):
    """The scene ``args.scene`` with the overrides of :func:`add_scene_overrides` applied
    (``--angle`` last, by :func:`turn_acquisition`)."""
    scene = _load_with_file_overrides(args)
    angle = getattr(args, "angle", None)
    if angle is not None:
        scene = turn_acquisition(scene, angle)
        log.debug("--angle %g: source at %s", angle, scene.source.position.tolist())
    return scene


def _load_with_file_overrides(args):
    """The scene ``args.scene`` with the overrides of :func:`add_scene_overrides` applied.

    Each override edits the parsed scene file before :func:`xray_viz.scene_file.scene_from_dict`
    checks it, so it is checked, and changes the scene, exactly as the key it sets would in
    the file. A value the file's checks refuse is reported with the option that gave it.

    Raises
    ------
    XrayVizError
        An override's value refused: ``--energy 900: frog.toml: [source] energy ...``.
    SceneError, SceneFileNotFoundError
        From :func:`xray_viz.load_scene`, for the file itself.
    """
    import copy
    import tomllib
    import warnings

    import xray_viz
    from xray_viz.errors import SceneError

    given = _given_overrides(args)
    if not given:
        scene = xray_viz.load_scene(args.scene)
        _log_scene(scene)
        return scene
    path = _scene_file(args.scene)
    from xray_viz.starter import framed_document, is_mesh_file

    try:
        original = (framed_document(path) if is_mesh_file(path)    # a mesh alone, framed
                    else tomllib.loads(path.read_bytes().decode("utf-8")))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, RecursionError):
        return xray_viz.load_scene(path)           # raises its own one-line error
    doc = copy.deepcopy(original)
    for option, value in given:
        _apply_override(doc, option, value)
        log.debug("%s sets %s", _shown_option(option, value), dict(OVERRIDES)[option])
    try:
        scene = _parse(doc, path)
    except SceneError as exc:
        # Whose value is refused: the file's own (it fails without the overrides too), one
        # override's (it fails alone), or the overrides' together.
        def fails(options):
            trial = copy.deepcopy(original)
            try:
                for option, value in given:
                    if option in options:
                        _apply_override(trial, option, value)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    _parse(trial, path)
            except (SceneError, XrayVizError):
                return True
            return False

        if fails(()):
            raise
        blamed = [(o, v) for o, v in given if fails((o,))] or given
        shown = " ".join(_shown_option(o, v) for o, v in blamed)
        raise XrayVizError(f"{shown}: {' '.join(str(exc).splitlines())}") from None
    _log_scene(scene)
    return scene


def _log_scene(scene):
    w, h = scene.detector.shape
    src = scene.source
    beam = f"{src.energy:g} keV" if src.spectrum is None else (
        f"{src.spectrum['kvp']:g} kVp spectrum" if "kvp" in src.spectrum else "a spectrum file")
    log.debug("scene %s: %d bodies, %s source at %s, %s; detector %d x %d pixels, pitch %s mm, "
              "noise %s, seed %s", scene.path, len(scene.bodies), src.kind,
              src.position.tolist(), beam, w, h, list(scene.detector.pitch),
              scene.detector.noise, scene.detector.seed)

