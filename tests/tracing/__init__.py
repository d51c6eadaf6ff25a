"""Tests of xray_viz.tracing: the engines, the fast rasteriser and its kernels, voxels."""
