"""File formats of thermal videos: one module per format, and the registries that map suffixes to loaders.

Formats (suffix -> module of this package): ``.npz`` / ``.npy`` (``numpy_formats``, also the ``.npz``
writer); ``.csv`` FLIR CSV exports with ``Frame N,`` blocks (``flir_csv``); ``.jpg`` FLIR radiometric JPEG, a
folder of them is one video (``flir_jpeg``); a folder of per-frame ``.csv`` / ``.txt`` matrices
(``matrices``); MATLAB ``.mat``, HDF5 ``.h5`` / ``.hdf5``, multi-page TIFF ``.tif`` / ``.tiff``
(``containers``); FLIR ``.fff`` frames and ``.seq`` / ``.csq`` sequences (``flir_seq``, on ``flir_fff``;
a folder of ``.fff`` frames is one video ordered by capture time).

A new format is one module with a loader ``(Path) -> RawVideo`` and one entry below. A loader in
:data:`RADIOMETRIC` also takes ``objects`` (:class:`~anra_torch.video.formats.flir_objects.ObjectParameters`);
one in :data:`LAZY_REGISTRY` opens a recording with its frames left unread (a frame source,
:class:`~anra_torch.video.lazy.FrameSource`).
"""

from anra_torch.video.core import Loader
from anra_torch.video.formats import containers, flir_csv, flir_jpeg, flir_seq, matrices, numpy_formats

__all__ = ["FOLDER_REGISTRY", "LAZY_REGISTRY", "RADIOMETRIC", "REGISTRY"]

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
    ".fff": flir_seq.load_flir_sequence,
    ".seq": flir_seq.load_flir_sequence,
    ".csq": flir_seq.load_flir_sequence,
}
"""File suffix (lower case, with the dot; may be compound such as ``.csv.gz``) -> loader."""

FOLDER_REGISTRY: dict[str, Loader] = {
    ".jpg": flir_jpeg.load_flir_jpeg_folder,
    ".jpeg": flir_jpeg.load_flir_jpeg_folder,
    ".csv": matrices.load_matrix_folder,
    ".txt": matrices.load_matrix_folder,
    ".fff": flir_seq.load_flir_folder,
}
"""Suffix of the frame files inside a folder (one file per frame) -> loader of the whole folder. ``.fff``
files make the folder theirs: text files beside them (ExifTool's dumps, notes) are not frames."""

RADIOMETRIC: frozenset[Loader] = frozenset(
    {
        flir_jpeg.load_flir_jpeg,
        flir_jpeg.load_flir_jpeg_folder,
        flir_seq.load_flir_sequence,
        flir_seq.load_flir_folder,
    }
)
"""The loaders of FLIR radiometric recordings: they take ``objects``, the object parameters that replace the
file's (emissivity, reflected temperature, distance, atmospheric temperature, humidity)."""

LAZY_REGISTRY = {
    ".fff": flir_seq.open_flir_sequence,
    ".seq": flir_seq.open_flir_sequence,
    ".csq": flir_seq.open_flir_sequence,
}
"""Suffix -> ``(Path, objects) -> RawVideo`` whose ``frames`` are left unread (read in chunks by
:func:`anra_torch.video.lazy.lazy_video`'s users)."""
