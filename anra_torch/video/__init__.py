"""Thermal video in: the :class:`Video` type, file formats, and the preparation steps before any analysis.

- :mod:`~anra_torch.video.core`: :class:`Video`, the frames with ``dt`` in s, ``dx`` in mm, timestamps and
  ``meta``, and its optional :class:`Truth`, what a simulation made it with;
- :mod:`~anra_torch.video.load`: :func:`load_video`, with one module per format and the suffix registries
  in :mod:`~anra_torch.video.formats`, FLIR files included, and :class:`ObjectParameters` overrides;
  :func:`save_npz`, the one ``.npz`` writer;
- frames left on disk and read in chunks: :class:`FrameSource`, :class:`LazyFrames`, :class:`FLIRFrames`;
- the steps: :func:`resample_uniform` for non-uniform timestamps, :func:`crop` and pixel masks,
  calibration tables, units and pixel-size intervals;
- :func:`prepare_video`: load, resample, roi and calibration in one call, as every command does it, with
  the one input policy: out-of-range samples masked and counted, :func:`input_warnings`;
- :func:`segment_phases`: baseline, heating and cooling from the data.

Shape:
    Frames ``(T, H, W)``, x along W, the columns, y along H, the rows.
"""

from anra_torch.video.calibration import (
    CalibrationTable,
    PixelSize,
    apply_calibration,
    load_calibration,
    to_unit,
)
from anra_torch.video.core import PathLike, RawVideo, SingleFrameError, Truth, Video
from anra_torch.video.formats import FOLDER_REGISTRY, LAZY_REGISTRY, RADIOMETRIC, REGISTRY
from anra_torch.video.formats.flir_csv import is_flir_csv
from anra_torch.video.formats.flir_objects import ObjectParameters
from anra_torch.video.formats.flir_seq import FLIRFrames, SequenceIndex, index_sequence
from anra_torch.video.formats.numpy_formats import save_npz
from anra_torch.video.lazy import FrameSource, LazyFrames, decimated, lazy_npz_fields, lazy_video
from anra_torch.video.load import TIMESTAMPS, load_video
from anra_torch.video.phases import Phase, hot_spot_signal, recording_phases, segment_phases
from anra_torch.video.prepare import STEPS, input_warnings, prepare_video
from anra_torch.video.resample import measured_frames, measured_part, resample_uniform
from anra_torch.video.roi import ROI, apply_mask, crop, dead_pixel_mask, parse_roi, reflection_mask

__all__ = [
    "CalibrationTable",
    "FLIRFrames",
    "FOLDER_REGISTRY",
    "FrameSource",
    "LAZY_REGISTRY",
    "LazyFrames",
    "ObjectParameters",
    "PathLike",
    "Phase",
    "PixelSize",
    "RADIOMETRIC",
    "REGISTRY",
    "ROI",
    "RawVideo",
    "STEPS",
    "SequenceIndex",
    "SingleFrameError",
    "TIMESTAMPS",
    "Truth",
    "Video",
    "apply_calibration",
    "apply_mask",
    "crop",
    "dead_pixel_mask",
    "decimated",
    "hot_spot_signal",
    "index_sequence",
    "input_warnings",
    "is_flir_csv",
    "lazy_npz_fields",
    "lazy_video",
    "load_calibration",
    "load_video",
    "measured_frames",
    "measured_part",
    "parse_roi",
    "prepare_video",
    "recording_phases",
    "reflection_mask",
    "resample_uniform",
    "save_npz",
    "segment_phases",
    "to_unit",
]
