"""Input preparation: the one path from a file to the frames every command analyses.

``load -> resample -> roi -> calibration``, in that order: timestamps are made uniform on the full frame, the
region is cut from the (resampled) frames in their own pixel coordinates, and the calibration table maps only
the values that will be analysed (its extrapolated fraction is counted on those). ``anra estimate``,
``diagnose``, ``features`` and ``batch`` all call :func:`prepare_video`, so they read a file the same way.
"""

from __future__ import annotations

from dataclasses import replace

from anra_torch.video.calibration import CalibrationTable, apply_calibration, load_calibration
from anra_torch.video.core import PathLike, Video
from anra_torch.video.load import load_video
from anra_torch.video.roi import ROI, crop, parse_roi

__all__ = ["STEPS", "prepare_video"]

STEPS = ("load", "resample", "roi", "calibration")
"""The steps in the order :func:`prepare_video` applies them (``meta["steps"]`` lists those done)."""


def prepare_video(
    path: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    timestamps: str = "uniform",
    roi: ROI | str | None = None,
    calibration: CalibrationTable | PathLike | None = None,
    need_dx: bool = True,
) -> Video:
    """Read a video and prepare it for analysis: load, resample, crop to ``roi``, calibrate.

    Args:
        path: the video file or folder (any format of :func:`~anra_torch.video.load_video`).
        dt: frame period in s (overrides the file).
        dx: pixel size in mm (overrides the file).
        timestamps: ``"uniform"`` (refuse non-uniform timestamps), ``"keep"`` or ``"resample"`` (interpolate
            them linearly onto their median step); see :func:`~anra_torch.video.load_video`.
        roi: region ``(x0, y0, width, height)`` in px, or its text ``"X0,Y0,W,H"``; None keeps the frame.
        calibration: a :class:`~anra_torch.video.CalibrationTable` or the path of a ``true,apparent`` CSV
            mapping apparent to true temperature; None keeps the values.
        need_dx: require a pixel size (every analysis does; False only to inspect a file).

    Returns:
        The prepared :class:`~anra_torch.video.Video`. Its ``meta`` says what was done: ``"steps"`` (the names
        of :data:`STEPS` done, in order), ``"resampled"`` (from what), ``"roi"`` (``[x0, y0, w, h]`` px),
        ``"calibration"`` (table and extrapolated fraction).

    Shape:
        Frames ``(T, H, W)`` in the file -> ``(T', height, width)`` (``T'`` after resampling).

    Raises:
        ValueError: every error of :func:`~anra_torch.video.load_video`, a bad or too large ``roi``, a bad
            calibration file, and (with ``need_dx``) no pixel size in the file nor in ``dx``.

    Example:
        >>> import tempfile, numpy as np
        >>> from anra_torch.video import save_npz
        >>> path = save_npz(tempfile.mkdtemp() + "/v.npz", np.zeros((6, 8, 8)), dt=0.04, dx=0.1)
        >>> video = prepare_video(path, roi="2,1,4,3")
        >>> tuple(video.frames.shape), video.meta["steps"], video.meta["roi"]
        ((6, 3, 4), ['load', 'roi'], [2, 1, 4, 3])
    """
    video = load_video(path, dt=dt, dx=dx, timestamps=timestamps)
    steps = ["load", "resample"] if "resampled" in video.meta else ["load"]
    if roi is not None:
        video = crop(video, parse_roi(roi) if isinstance(roi, str) else roi)
        steps.append("roi")
    if calibration is not None:
        table = calibration if isinstance(calibration, CalibrationTable) else load_calibration(calibration)
        video = apply_calibration(video, table)
        steps.append("calibration")
    if need_dx and video.dx is None:
        raise ValueError(f"{video.source}: no pixel size: the file has no 'dx'; pass --dx in mm")
    return replace(video, meta={**video.meta, "steps": steps})
