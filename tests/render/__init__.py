"""Tests of xray_viz.render, geometry, attenuation, lod, bodies and _memory: the pipeline from a scene to its images."""
