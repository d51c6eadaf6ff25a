"""DICOM Segmentation (DICOM-SEG) objects as label maps, read with highdicom.

A DICOM-SEG stores each segment's frames (binary, fractional, or a LABELMAP) with their
positions in the patient frame of reference; highdicom (``Segmentation.get_volume``) puts them
on a regular grid. Segment numbers become label values, so a ``[[labels]]`` table refers to
them as to the labels of a NIfTI map:

.. code-block:: toml

    [[labels]]
    file = "seg.dcm"
    materials = { 1 = "Bone, Cortical (ICRP)", 2 = "Tissue, Soft (ICRP)" }
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from xray_viz.errors import MeshError, reader_reason

__all__ = ["read_dicom_seg", "SEGMENTATION_STORAGE"]

#: SOP classes of DICOM Segmentation Storage (the classic one and the 2024 Label Map one).
SEGMENTATION_STORAGE = ("1.2.840.10008.5.1.4.1.1.66.4", "1.2.840.10008.5.1.4.1.1.66.7")

#: DICOM's patient coordinates (LPS+) to the scene's (RAS+): x and y negated.
_LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


def read_dicom_seg(path) -> tuple[np.ndarray, np.ndarray, dict[int, str]]:
    """Read a DICOM-SEG file as a label map.

    Parameters
    ----------
    path : path-like
        A DICOM Segmentation (binary, fractional thresholded at one half, or label map) of a
        regularly spaced volume.

    Returns
    -------
    labels : (I, J, K) int64
        The segment number of each voxel, 0 outside every segment.
    affine : (4, 4) float
        Voxel index to scene mm (RAS+: DICOM's LPS with x and y negated, as
        :func:`xray_viz.meshes.volumes.read_volume` does for every format).
    names : dict
        Segment number to its label (``SegmentLabel``).

    Raises
    ------
    MeshError
        highdicom is missing, the file is not a DICOM Segmentation, its segments overlap (a
        label map cannot hold two labels in a voxel), or its frames do not form a regular
        volume; one line each.

    Examples
    --------
    >>> from xray_viz.meshes.dicom_seg import SEGMENTATION_STORAGE
    >>> SEGMENTATION_STORAGE[0]
    '1.2.840.10008.5.1.4.1.1.66.4'
    """
    path = Path(path)
    try:
        import highdicom as hd
        import pydicom
    except ImportError:
        raise MeshError(f"{path}: reading a DICOM-SEG needs highdicom: "
                        "pip install 'xray_viz[volumes]'") from None
    try:
        ds = pydicom.dcmread(path)
    except Exception as exc:
        raise MeshError(f"{path}: cannot read DICOM: {reader_reason(exc, limit=120)}") from None
    sop = str(ds.get("SOPClassUID", ""))
    if sop not in SEGMENTATION_STORAGE:
        raise MeshError(f"{path}: not a DICOM Segmentation (SOP class {sop or 'missing'}, "
                        f"modality {ds.get('Modality', 'missing')}): a single .dcm file is read "
                        "as a DICOM-SEG label map; give a CT series as the folder of its slices")
    try:
        seg = hd.seg.Segmentation.from_dataset(ds)
        fractional = str(getattr(seg, "SegmentationType", "")) == "FRACTIONAL"
        if fractional:
            volume = seg.get_volume(combine_segments=False)
            stack = np.asarray(volume.array) >= 0.5          # (I, J, K, segments)
            numbers = np.asarray(seg.segment_numbers, dtype=np.int64)
            if np.any(stack.sum(axis=-1) > 1):
                raise ValueError("segments overlap")
            labels = (stack * numbers).sum(axis=-1)
        else:
            volume = seg.get_volume(combine_segments=True)
            labels = np.asarray(volume.array)
    except MeshError:
        raise
    except Exception as exc:
        text = reader_reason(exc)
        if "overlap" in text.lower():
            raise MeshError(f"{path}: its segments overlap; a label map holds one label per "
                            "voxel: split the segmentation into one [[labels]] file per "
                            "layer") from None
        raise MeshError(f"{path}: cannot read the DICOM-SEG as a volume: {text}") from None
    names = {int(item.SegmentNumber): str(getattr(item, "SegmentLabel", ""))
             for item in ds.SegmentSequence}
    return (np.asarray(labels, dtype=np.int64), _LPS_TO_RAS @ np.asarray(volume.affine, float),
            names)
