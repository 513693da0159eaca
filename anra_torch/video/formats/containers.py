"""Array containers: MATLAB ``.mat`` (scipy), HDF5 ``.h5`` / ``.hdf5`` (h5py), multi-page TIFF (tifffile).

MATLAB and HDF5 files hold the frames under ``frames`` (or as their only 3D array / dataset) in
``(T, H, W)`` order, with optional scalars ``dt`` in s, ``dx`` in mm, ``unit`` and a vector ``t`` in s; HDF5
also reads them from the frames dataset's attributes. A multi-page TIFF holds one page per frame; an
ImageJ ``finterval`` in s is taken as ``dt``. Every reader needs the ``formats`` extra.
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

import numpy as np

from anra_torch.checks import one_line
from anra_torch.video.core import RawVideo

__all__ = ["load_hdf5", "load_mat", "load_tiff"]

_SPACING = ("dt", "dx", "t")


def _require(module: str, what: str) -> Any:
    try:
        return importlib.import_module(module)
    except ImportError as err:
        raise ImportError(f"reading {what} needs {module}: pip install anra_torch[formats]") from err


def _pick_frames(arrays: dict[str, np.ndarray], path: Path, kind: str) -> str:
    if "frames" in arrays:
        return "frames"
    cubes = [k for k, v in arrays.items() if np.ndim(v) == 3]
    if len(cubes) == 1:
        return cubes[0]
    found = ", ".join(f"{k} {tuple(np.shape(v))}" for k, v in arrays.items()) or "nothing"
    raise ValueError(f"{path}: no 'frames' {kind} and not exactly one 3D array (T, H, W); found {found}")


def _raw(arrays: dict[str, Any], key: str, fmt: str) -> RawVideo:
    raw = RawVideo(frames=np.asarray(arrays[key]), meta={"format": fmt})
    for name in _SPACING:
        if name in arrays:
            value = np.asarray(arrays[name], dtype=np.float64)
            setattr(raw, name, value.reshape(-1) if name == "t" else value)
    if "unit" in arrays:
        unit = arrays["unit"]
        raw.meta["unit"] = unit.decode() if isinstance(unit, bytes) else str(np.asarray(unit).reshape(-1)[0])
    return raw


def load_mat(path: Path) -> RawVideo:
    """MATLAB ``.mat`` (v4-v7.2; v7.3 files are HDF5, save them as ``.h5``)."""
    io = _require("scipy.io", "MATLAB .mat files")
    try:
        data = io.loadmat(path)
    except NotImplementedError as err:
        raise ValueError(f"{path}: MATLAB v7.3 file; it is HDF5 inside: rename it to .h5") from err
    except Exception as err:  # scipy raises ValueError, TypeError, OSError... on a damaged file
        raise ValueError(
            f"{path}: cannot read as .mat ({one_line(err, kind=True)}); the file may be corrupt"
        ) from err
    arrays = {k: v for k, v in data.items() if not k.startswith("__")}
    return _raw(arrays, _pick_frames(arrays, path, "variable"), "mat")


def load_hdf5(path: Path) -> RawVideo:
    """HDF5 with a ``frames`` dataset (or one 3D dataset) and optional ``dt``, ``dx``, ``t``, ``unit``."""
    h5py = _require("h5py", "HDF5 files")
    try:
        with h5py.File(path, "r") as handle:
            arrays: dict[str, Any] = {}
            handle.visititems(
                lambda name, obj: arrays.update({name: obj}) if isinstance(obj, h5py.Dataset) else None
            )
            key = _pick_frames(
                {k: np.empty(v.shape) if v.ndim == 3 else v[()] for k, v in arrays.items()}, path, "dataset"
            )
            values = {k: (v[()] if k == key or v.ndim < 3 else None) for k, v in arrays.items()}
            values.update({k: v for k, v in handle[key].attrs.items() if k in (*_SPACING, "unit")})
    except (OSError, KeyError, RuntimeError) as err:
        raise ValueError(
            f"{path}: cannot read as HDF5 ({one_line(err, kind=True)}); the file may be truncated or corrupt"
        ) from err
    return _raw(values, key, "hdf5")


def load_tiff(path: Path) -> RawVideo:
    """Multi-page TIFF, one page per frame (ImageJ ``finterval`` in s becomes ``dt``; the ``t``, ``dx`` and
    ``unit`` of a JSON description, as ``anra convert`` writes them, are read too)."""
    tifffile = _require("tifffile", "TIFF files")
    try:
        with tifffile.TiffFile(path) as tif:
            frames = tif.asarray()
            imagej = tif.imagej_metadata or {}
            shaped = {k: v for k, v in (tif.shaped_metadata or ({},))[0].items() if v is not None}
    except Exception as err:  # tifffile raises TiffFileError, ValueError, OSError... on a damaged file
        raise ValueError(
            f"{path}: cannot read as TIFF ({one_line(err, kind=True)}); the file may be truncated or corrupt"
        ) from err
    if frames.ndim == 2:
        frames = frames[None]
    raw = RawVideo(frames=frames, meta={"format": "tiff"})
    if "finterval" in imagej:
        raw.dt = float(imagej["finterval"])
    if "unit" in imagej and imagej["unit"] not in ("micron", "pixel", "\\u00B5m"):
        raw.meta["unit"] = str(imagej["unit"])
    for key in ("dt", "dx", "t"):
        if key in shaped:
            setattr(raw, key, np.asarray(shaped[key], dtype=np.float64))
    if "t_resolution" in shaped:
        raw.meta["t_resolution"] = float(shaped["t_resolution"])
    if "unit" in shaped:
        raw.meta["unit"] = str(shaped["unit"])
    return raw
