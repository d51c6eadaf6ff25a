"""Tests of xray_viz.gradients and xray_viz.registration: pose gradients, 2D/3D registration."""
