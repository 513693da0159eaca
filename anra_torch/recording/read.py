"""How every command reads a recording: prepared in memory, or left on disk to be read in chunks.

:func:`open_recording` is the one reading policy of ``anra estimate``, ``diagnose``, ``features`` and
``batch``. A ``.npy`` file or an uncompressed ``.npz`` above ``on_disk_above`` pixel values, with no region
of interest or calibration to apply, stays on disk (:func:`~anra_torch.video.lazy_video`: the frames
are read chunk by chunk by whoever needs them, :attr:`Video.on_disk <anra_torch.video.Video.on_disk>`);
anything else is loaded and prepared (:func:`~anra_torch.video.prepare_video`: non-uniform timestamps
resampled and said so, region, calibration, out-of-range samples masked).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from anra_torch.video import (
    ROI,
    CalibrationTable,
    PathLike,
    SingleFrameError,
    Video,
    lazy_video,
    prepare_video,
)

__all__ = ["input_record", "open_recording"]


def open_recording(
    path: PathLike,
    *,
    dt: float | None = None,
    dx: float | None = None,
    roi: ROI | str | None = None,
    calibration: CalibrationTable | PathLike | None = None,
    need_dx: bool = True,
    need_time: bool = True,
    on_disk_above: int | None = None,
    **objects: float,
) -> Video:
    """The recording at ``path``, as every command reads it.

    Args:
        path: a video file or a folder of frame files, in any format of :func:`~anra_torch.video.load_video`.
        dt: frame period in s, overriding the file's.
        dx: pixel size in mm, overriding the file's.
        roi: analyse only this region ``(x0, y0, width, height)`` in px, or its text ``"X0,Y0,W,H"``.
        calibration: map apparent to true temperatures by a table or a ``true,apparent`` CSV.
        need_dx: require a pixel size; False where none is needed, as for the dose features.
        need_time: refuse a single frame, which has no time axis, in one message whether or not ``dt`` is
            given; False where one frame held for ``dt`` will do.
        on_disk_above: leave a ``.npy``, uncompressed ``.npz`` or FLIR sequence of more pixel values than
            this on disk; 0 always, None never. A region or a calibration always loads the recording.
        **objects: a FLIR recording's object parameters replacing the file's, as
            :func:`~anra_torch.video.load_video` takes them.

    Returns:
        A :class:`~anra_torch.video.Video`; its frames unread when left on disk.

    Shape:
        ``frames`` ``(T, H, W)``.

    Raises:
        ValueError: in one line, an unreadable file, missing spacing, a bad region or calibration, a single
            frame with ``need_time``.
    """
    single = ValueError(
        f"{Path(path)}: a single frame has no time axis; this needs frames over time (a video)"
    )
    try:
        video = _open(path, dt, dx, roi, calibration, need_dx, on_disk_above, objects)
    except SingleFrameError:
        if need_time:
            raise single from None
        raise
    if need_time and video.frames.shape[0] == 1:
        raise single
    return video


def _open(
    path: PathLike,
    dt: float | None,
    dx: float | None,
    roi: ROI | str | None,
    calibration: CalibrationTable | PathLike | None,
    need_dx: bool,
    on_disk_above: int | None,
    objects: dict[str, float],
) -> Video:
    if on_disk_above is not None and roi is None and calibration is None:
        lazy = lazy_video(path, dt=dt, dx=dx, **objects)
        if lazy is not None and math.prod(lazy.frames.shape) > on_disk_above:
            return lazy
    return prepare_video(
        path,
        dt=dt,
        dx=dx,
        timestamps="resample",  # only non-uniform timestamps are resampled; the output says so
        roi=roi,
        calibration=calibration,
        need_dx=need_dx,
        **objects,
    )


def input_record(video: Video) -> dict[str, Any]:
    """What the reading did: ``timestamps`` (where a folder of frame files recorded its times),
    ``resampled`` (from what), ``roi`` in px, ``calibration``, ``masked_values`` (samples masked as not
    finite or beyond +-1e6), ``object_parameters`` (a FLIR recording's emissivity, reflected_temp,
    distance, atmospheric_temp, humidity: each ``value``, ``unit`` and ``source``, ``"file"`` or
    ``"argument"``); null when not done."""
    keys = ("timestamps", "resampled", "roi", "calibration", "masked_values", "object_parameters")
    return {key: video.meta.get(key) for key in keys}
