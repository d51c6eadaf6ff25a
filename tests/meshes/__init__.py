"""Tests of xray_viz.meshes: reading, checking and repairing meshes, primitives, label maps and CT volumes as bodies, gVXR scenes."""
