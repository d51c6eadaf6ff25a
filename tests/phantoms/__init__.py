"""Tests of xray_viz.phantoms: the bundled phantom library."""
