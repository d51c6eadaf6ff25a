"""Tests of xray_viz.physics: spectra, materials, the image formation, the detector, dosimetry, the anti-scatter grid."""
