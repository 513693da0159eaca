"""Input preparation: the one path from a file to the frames every command analyses.

``load -> resample -> roi -> calibration``, in that order: timestamps are made uniform on the full frame, the
region is cut from the (resampled) frames in their own pixel coordinates, and the calibration table maps only
the values that will be analysed (its extrapolated fraction is counted on those). ``anra estimate``,
``diagnose``, ``features`` and ``batch`` all call :func:`prepare_video`, so they read a file the same way.

The input policy lives here, once for every command. As the file is read (before resampling, which would
blend a bad sample into its neighbours) and again after roi and calibration:

- a sample that cannot be a measurement (NaN, an infinity, or beyond ``+-``
  :data:`~anra_torch.checks.VALUE_LIMIT` = 1e6 data units: a float overflow, a sensor's error code) is
  masked (set to NaN, which every analysis drops and counts), never refused on its own;
  ``meta["masked_values"]`` counts them and :func:`input_warnings` says it in one line;
- a video with no sample left (all NaN, or a region holding none) is refused;
- ``dt`` and ``dx`` must lie in :data:`~anra_torch.checks.SPACING_RANGE` (1e-6 to 1e6 s or mm): beyond,
  the arithmetic leaves the float range and no number it gives would mean anything.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from anra_torch.checks import in_range_values, spacing_in_range
from anra_torch.video.calibration import CalibrationTable, apply_calibration, load_calibration
from anra_torch.video.core import PathLike, Video
from anra_torch.video.load import load_video
from anra_torch.video.roi import ROI, crop, parse_roi

__all__ = ["STEPS", "input_warnings", "prepare_video"]

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
    **objects: float | None,
) -> Video:
    """Read a video and prepare it for analysis: load, resample, crop to ``roi``, calibrate.

    Args:
        path: the video file or folder (any format of :func:`~anra_torch.video.load_video`).
        dt: frame period in s (overrides the file).
        dx: pixel size in mm (overrides the file).
        timestamps: ``"uniform"``, ``"keep"`` or ``"resample"``, as in :func:`~anra_torch.video.load_video`.
        roi: region ``(x0, y0, width, height)`` in px, or its text ``"X0,Y0,W,H"``; None keeps the frame.
        calibration: a :class:`~anra_torch.video.CalibrationTable` or the path of a ``true,apparent`` CSV
            mapping apparent to true temperature; None keeps the values.
        need_dx: require a pixel size (every analysis does; False only to inspect a file).
        **objects: a FLIR radiometric file's object parameters, as in :func:`~anra_torch.video.load_video`.

    Returns:
        The prepared :class:`~anra_torch.video.Video`; ``meta["steps"]`` names the :data:`STEPS` done, in
        order, and ``meta`` what each did (``docs/reference/outputs.md``, the estimate's ``input``).

    Shape:
        Frames ``(T, H, W)`` in the file -> ``(T', height, width)`` (``T'`` after resampling).

    Raises:
        ValueError: every error of :func:`~anra_torch.video.load_video`, no finite sample within the limit
            (in the file or in ``roi``), ``dt`` or ``dx`` outside the spacing range, a bad or too large
            ``roi``, a bad calibration file, and (with ``need_dx``) no pixel size in the file nor in ``dx``.

    Example:
        >>> import tempfile, numpy as np
        >>> from anra_torch.video import save_npz
        >>> path = save_npz(tempfile.mkdtemp() + "/v.npz", np.zeros((6, 8, 8)), dt=0.04, dx=0.1)
        >>> video = prepare_video(path, roi="2,1,4,3")
        >>> tuple(video.frames.shape), video.meta["steps"], video.meta["roi"]
        ((6, 3, 4), ['load', 'roi'], [2, 1, 4, 3])
    """
    video = _spacing_checked(
        load_video(path, dt=dt, dx=dx, timestamps=timestamps, mask_values=True, **objects)
    )
    steps = ["load", "resample"] if "resampled" in video.meta else ["load"]
    if roi is not None:
        video = crop(video, parse_roi(roi) if isinstance(roi, str) else roi)
        steps.append("roi")
    if calibration is not None:
        table = calibration if isinstance(calibration, CalibrationTable) else load_calibration(calibration)
        video = apply_calibration(video, table)
        steps.append("calibration")
    if roi is not None or calibration is not None:
        video = _checked(video, " in the region" if roi is not None else "")
    if need_dx and video.dx is None:
        raise ValueError(f"{video.source}: no pixel size: the file has no 'dx'; pass --dx in mm")
    return replace(video, meta={**video.meta, "steps": steps})


def _spacing_checked(video: Video) -> Video:
    """``dt`` and ``dx`` within the spacing range (module docstring)."""
    try:
        spacing_in_range(video.dt, "dt", "s")
        if video.dx is not None:
            spacing_in_range(video.dx, "dx", "mm")
    except ValueError as err:
        raise ValueError(f"{video.source}: {err}") from None
    return video


def _checked(video: Video, where: str) -> Video:
    """After roi and calibration: what the calibration pushed beyond the limit masked and added to the
    count, refused when no sample is left (``where``: which frames, for the message)."""
    try:
        frames, found = in_range_values(video.frames, name=f"frames{where}")
    except ValueError as err:
        raise ValueError(f"{video.source}: {err}") from None
    if not found["beyond_limit"]:
        return video
    before = video.meta.get("masked_values")
    if before is not None:  # the samples masked on reading are NaN now: only the new ones are added
        largest = max(before["largest"] or 0.0, found["largest"])
        found = {**before, "beyond_limit": before["beyond_limit"] + found["beyond_limit"], "largest": largest}
    return replace(video, frames=frames, meta={**video.meta, "masked_values": found})


def input_warnings(video: Video) -> list[str]:
    """One line per input problem :func:`prepare_video` found and masked (empty when none), for the
    ``warnings`` of every command's record.

    Shape:
        No tensors.
    """
    found: dict[str, Any] | None = video.meta.get("masked_values")
    if not found:
        return list(video.meta.get("input_warnings", []))  # what a loader left out (a cut-off frame)
    parts = []
    if found["non_finite"]:
        parts.append(f"{found['non_finite']} non-finite")
    if found["beyond_limit"]:
        parts.append(
            f"{found['beyond_limit']} beyond +-{found['limit']:g} {video.unit}, the largest "
            f"{found['largest']:.3g}: not a measurement"
        )
    masked = found["non_finite"] + found["beyond_limit"]
    lines = [f"input: {masked} of {found['samples']} samples masked ({'; '.join(parts)})"]
    return lines + list(video.meta.get("input_warnings", []))
