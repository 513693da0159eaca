"""Thermal videos from files and folders (see :mod:`anra_torch.io.video`); one module per format.

Formats (suffix -> module): ``.npz`` / ``.npy`` (:mod:`~anra_torch.io.numpy_formats`); ``.csv`` FLIR CSV
exports with ``Frame N,`` blocks (:mod:`~anra_torch.io.flir_csv`); ``.jpg`` FLIR radiometric JPEG, a folder of
them is one video (:mod:`~anra_torch.io.flir_jpeg`); a folder of per-frame ``.csv`` / ``.txt`` matrices
(:mod:`~anra_torch.io.matrices`); MATLAB ``.mat``, HDF5 ``.h5`` / ``.hdf5``, multi-page TIFF ``.tif`` /
``.tiff`` (:mod:`~anra_torch.io.containers`).
"""

from anra_torch.io import containers, flir_csv, flir_jpeg, matrices, numpy_formats
from anra_torch.io.video import (
    FOLDER_REGISTRY,
    REGISTRY,
    TIMESTAMPS,
    PathLike,
    RawVideo,
    Video,
    load_video,
    save_npz,
)

REGISTRY.update(
    {
        ".npz": numpy_formats.load_npz,
        ".npy": numpy_formats.load_npy,
        ".csv": flir_csv.load_flir_csv,
        ".jpg": flir_jpeg.load_flir_jpeg,
        ".jpeg": flir_jpeg.load_flir_jpeg,
        ".mat": containers.load_mat,
        ".h5": containers.load_hdf5,
        ".hdf5": containers.load_hdf5,
        ".tif": containers.load_tiff,
        ".tiff": containers.load_tiff,
    }
)
FOLDER_REGISTRY.update(
    {
        ".jpg": flir_jpeg.load_flir_jpeg_folder,
        ".jpeg": flir_jpeg.load_flir_jpeg_folder,
        ".csv": matrices.load_matrix_folder,
        ".txt": matrices.load_matrix_folder,
    }
)

__all__ = [
    "FOLDER_REGISTRY",
    "REGISTRY",
    "TIMESTAMPS",
    "PathLike",
    "RawVideo",
    "Video",
    "load_video",
    "save_npz",
]
