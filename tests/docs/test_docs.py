"""The examples in the docstrings run and print what they say."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = [
    "xray_viz", "xray_viz.scene", "xray_viz.geometry", "xray_viz.tracing.intersect",
    "xray_viz.tracing.hits", "xray_viz.attenuation", "xray_viz.render", "xray_viz.output",
    "xray_viz.phantoms", "xray_viz.physics.imaging", "xray_viz.physics.detector",
    "xray_viz.physics.heel",
]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             extraglobs={"dataclasses": importlib.import_module("dataclasses")})
    assert result.attempted > 0 and result.failed == 0
