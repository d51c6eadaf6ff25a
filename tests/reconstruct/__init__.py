"""Tests of xray_viz.reconstruct: reconstruction through RTK and mbirjax."""
