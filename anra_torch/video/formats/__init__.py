"""File formats of thermal videos: one module per format, and the registries that map suffixes to loaders.

Formats (suffix -> module of this package): ``.npz`` / ``.npy`` (``numpy_formats``, also the ``.npz``
writer); ``.csv`` FLIR CSV exports with ``Frame N,`` blocks (``flir_csv``); ``.jpg`` FLIR radiometric JPEG, a
folder of them is one video (``flir_jpeg``); a folder of per-frame ``.csv`` / ``.txt`` matrices
(``matrices``); MATLAB ``.mat``, HDF5 ``.h5`` / ``.hdf5``, multi-page TIFF ``.tif`` / ``.tiff``
(``containers``).

A new format is one module with a loader ``(Path) -> RawVideo`` and one entry below.
"""

from anra_torch.video.core import Loader
from anra_torch.video.formats import containers, flir_csv, flir_jpeg, matrices, numpy_formats

__all__ = ["FOLDER_REGISTRY", "REGISTRY"]

REGISTRY: dict[str, Loader] = {
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
"""File suffix (lower case, with the dot; may be compound such as ``.csv.gz``) -> loader."""

FOLDER_REGISTRY: dict[str, Loader] = {
    ".jpg": flir_jpeg.load_flir_jpeg_folder,
    ".jpeg": flir_jpeg.load_flir_jpeg_folder,
    ".csv": matrices.load_matrix_folder,
    ".txt": matrices.load_matrix_folder,
}
"""Suffix of the frame files inside a folder (one file per frame) -> loader of the whole folder."""
