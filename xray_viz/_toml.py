"""Writing scene documents as TOML text: the one writer (tomlkit) behind
:meth:`xray_viz.scene.Scene.to_toml`, :func:`xray_viz.meshes.gvxr.to_toml` and the tests' and
phantoms' scene files."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np


def plain(value):
    """A value as TOML holds it: NumPy arrays and numbers as Python lists and numbers, mapping
    keys as strings.

    Examples
    --------
    >>> plain({"a": np.arange(2), 3: np.float64(0.5)})
    {'a': [0, 1], '3': 0.5}
    """
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def dumps(doc: Mapping, *, header: str = "") -> str:
    """``doc`` as TOML text (tables as ``[name]``, arrays of tables as ``[[name]]``), after
    ``header`` as comment lines.

    Examples
    --------
    >>> print(dumps({"source": {"position": np.zeros(3)}}, header="a scene"))
    # a scene
    <BLANKLINE>
    [source]
    position = [0.0, 0.0, 0.0]
    <BLANKLINE>
    """
    import tomlkit

    comments = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return comments + ("\n" if comments else "") + tomlkit.dumps(plain(doc))
