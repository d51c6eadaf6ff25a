"""Tests of xray_viz.montecarlo, xray_viz.transport and xray_viz.scatter_kernel: the photon transport and scatter in the images."""
