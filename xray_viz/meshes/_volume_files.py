"""Which files are volumes (label maps, CTs): the suffixes, with no import of a reader.

:mod:`xray_viz.bodies` asks it which bodies were meshed from a volume (their
``source_file``), to rank them below the scene's own ``[[body]]`` meshes; the readers are in
:mod:`xray_viz.meshes.volumes`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["NIFTI_SUFFIXES", "ITK_SUFFIXES", "DICOM_SEG_SUFFIXES", "VOLUME_SUFFIXES",
           "is_volume_path"]

#: File suffixes read as volumes (a folder is read as a DICOM series).
NIFTI_SUFFIXES = (".nii", ".nii.gz")
ITK_SUFFIXES = (".nrrd", ".nhdr", ".mha", ".mhd")
#: A single DICOM file is a DICOM-SEG label map (:mod:`xray_viz.meshes.dicom_seg`).
DICOM_SEG_SUFFIXES = (".dcm",)
VOLUME_SUFFIXES = NIFTI_SUFFIXES + ITK_SUFFIXES + DICOM_SEG_SUFFIXES


def is_volume_path(path) -> bool:
    """True for a file name that :func:`~xray_viz.meshes.volumes.read_volume` reads, or a
    folder (a DICOM series).

    Examples
    --------
    >>> is_volume_path("seg.nii.gz"), is_volume_path("a.MHA"), is_volume_path("ball.stl")
    (True, True, False)
    """
    p = Path(path)
    name = p.name.lower()
    return p.is_dir() or any(name.endswith(s) for s in VOLUME_SUFFIXES)
