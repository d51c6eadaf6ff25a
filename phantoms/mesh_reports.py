"""Write the bundled phantoms' mesh reports and inside tests shipped with the package:
``python phantoms/mesh_reports.py`` (after a change of a phantom's meshes or of the checking
code, ``xray_viz/meshes/repair.py``, ``_check_kernels.py`` or ``tracing/hits.py``:
``tests/meshes/test_report_cache.py`` says when). Writes ``phantoms/mesh-reports.json``, read by
:func:`xray_viz.meshes._report_cache.shipped`.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import xray_viz
from xray_viz import _cache, phantoms
from xray_viz.meshes import _report_cache


def write_shipped(path=_report_cache._SHIPPED_SOURCE) -> int:
    """Load every bundled phantom with the running checker, the cache in a temporary folder
    and nothing shipped, and write the reports and inside tests its loads made to ``path``
    (the file of :func:`xray_viz.meshes._report_cache.shipped`); returns how many
    reports."""
    old = {k: os.environ.get(k) for k in (_cache.ENV, "XRAY_VIZ_SHIPPED_REPORTS")}
    with tempfile.TemporaryDirectory() as tmp:
        os.environ[_cache.ENV] = tmp
        os.environ["XRAY_VIZ_SHIPPED_REPORTS"] = "off"
        try:
            for name in phantoms.names():
                xray_viz.load_scene(name).bodies.precedence     # the inside tests too
            found = {}
            for kind, field in (("mesh-reports", "report"), ("mesh-pairs", "inside")):
                found[kind] = {}
                for f in sorted((Path(tmp) / kind).glob("*.json")):
                    data = json.loads(f.read_text(encoding="utf-8"))
                    if data.get("format") == _report_cache.FORMAT:
                        found[kind][f.stem] = data[field]
        finally:
            for k, v in old.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    text = json.dumps({"format": _report_cache.FORMAT, "reports": found["mesh-reports"],
                       "pairs": found["mesh-pairs"]}, indent=1, sort_keys=True)
    Path(path).write_text(text + "\n", encoding="utf-8")
    _report_cache._shipped_file.cache_clear()
    return len(found["mesh-reports"])


if __name__ == "__main__":
    print(f"wrote {write_shipped()} reports to {_report_cache._SHIPPED_SOURCE}")
