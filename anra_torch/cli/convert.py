"""``anra convert FILE -o OUT``: any recording ``anra`` reads, written as ``.npz``, ``.h5`` or ``.tif``.

The frames are read and written chunk by chunk, never held whole, with a progress bar on stderr when it is
a terminal. ``--frames START:STOP`` keeps frames ``START .. STOP - 1`` by Python slice bounds,
``--roi X0,Y0,W,H`` a region in px; the object flags recompute a FLIR recording's temperatures. Every
format holds ``frames``, ``t``, ``dx``, ``unit`` and ``meta``, and each reader of ``anra`` reads it back;
what each entry holds and how each format stores it: ``docs/reference/outputs.md``, section
``anra convert``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from anra_torch.checks import atomic_output, check_output
from anra_torch.cli.arguments import (
    add_object_arguments,
    add_spacing_arguments,
    json_line,
    number,
    object_parameters,
)
from anra_torch.video import (
    LAZY_REGISTRY,
    LazyFrames,
    ObjectParameters,
    SingleFrameError,
    lazy_npz_fields,
    load_video,
    parse_roi,
)

__all__ = ["CHUNK_VALUES", "WRITERS", "add_parser", "run"]

CHUNK_VALUES = 1 << 24
"""Pixel values read and written at a time (64 MB of float32)."""


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``convert`` to the ``anra`` subcommands (``commands``: what ``add_subparsers`` returned)."""
    parser = commands.add_parser(
        "convert",
        help="write a recording (FLIR .seq/.csq/.fff/.jpg, .npz, ...) as .npz, .h5 or .tif",
        description="Convert any recording anra reads to .npz, .h5 or .tif, chunk by chunk: frames (T, H, W) "
        "as float32 in degrees Celsius for FLIR files, t (s) per frame, dx (mm) when known, and the "
        "camera metadata as JSON text (meta).",
    )
    parser.add_argument("video", metavar="FILE", help="the recording (a file, or a folder of frame files)")
    parser.add_argument(
        "-o", "--out", required=True, metavar="OUT", help=f"output file ({', '.join(WRITERS)})"
    )
    parser.add_argument("--frames", metavar="START:STOP", help="keep frames START .. STOP - 1 (slice bounds)")
    parser.add_argument(
        "--roi", metavar="X0,Y0,W,H", help="keep this region (px: column, row, width, height)"
    )
    add_spacing_arguments(parser, "the file")
    add_object_arguments(parser)
    parser.add_argument(
        "--chunk-values",
        type=number("pixel values", positive=True),
        default=CHUNK_VALUES,
        metavar="N",
        help=f"pixel values read and written at a time (default {CHUNK_VALUES})",
    )
    parser.set_defaults(run=run)


# ------------------------------------------------------------------------------------------ source
def _plain(value: Any) -> Any:
    """JSON for numpy scalars and arrays in the metadata."""
    if isinstance(value, np.generic | np.ndarray):
        return value.tolist()
    return str(value)


def _source(args: argparse.Namespace) -> tuple[Any, np.ndarray, float | None, dict[str, Any]]:
    """The frames (a :class:`FrameSource` where the file is read lazily, else in memory), each frame's time
    in s, the pixel size in mm and the metadata."""
    path = Path(args.video)
    objects = object_parameters(args)
    suffix = path.suffix.lower()
    if suffix in LAZY_REGISTRY and path.is_file():
        raw = LAZY_REGISTRY[suffix](path, objects=ObjectParameters(**objects) if objects else None)
        meta = dict(raw.meta)
        t = np.asarray(raw.t, dtype=np.float64)
        if args.dt is not None:
            t, meta["dt_source"] = np.arange(len(raw.frames)) * args.dt, "argument"
        return raw.frames, t, args.dx, meta
    if suffix in (".npy", ".npz") and path.is_file() and not objects:
        found = _numpy_source(path, args)
        if found is not None:
            return found
    try:
        video = load_video(path, dt=args.dt, dx=args.dx, timestamps="keep", **objects)
    except SingleFrameError:  # one frame (a folder of one .fff): its one time is 0 s, no period is needed
        video = load_video(path, dt=1.0, dx=args.dx, **objects)
        video.meta.pop("dt_source", None)
    t = video.t.numpy() if video.t is not None else np.arange(video.frames.shape[0]) * video.dt
    return video.frames.numpy(), t, video.dx, dict(video.meta)


def _numpy_source(path: Path, args: argparse.Namespace) -> tuple[Any, np.ndarray, float | None, dict] | None:
    """A ``.npy`` / uncompressed ``.npz`` read lazily, with its times and spacing; None for a compressed one
    (the loader reads it whole)."""
    try:
        frames = LazyFrames(path)
    except ValueError:
        return None
    fields = lazy_npz_fields(path) if path.suffix.lower() == ".npz" else {}
    n = len(frames)
    if args.dt is not None:
        t = np.arange(n) * args.dt
    elif "t" in fields:
        t = np.asarray(fields["t"], dtype=np.float64).reshape(-1)
        if t.shape != (n,):
            raise ValueError(f"{path}: t must hold {n} timestamps in s (one per frame), got {t.shape}")
    elif "dt" in fields:
        t = np.arange(n) * float(fields["dt"])
    else:
        raise ValueError(f"{path}: no frame period: the file has neither 'dt' nor 't'; pass --dt in s")
    dx = args.dx if args.dx is not None else (float(fields["dx"]) if "dx" in fields else None)
    meta = {"format": path.suffix.lower()}
    if "unit" in fields:
        meta["unit"] = str(fields["unit"])
    return frames, t, dx, meta


# ------------------------------------------------------------------------------------------ writers
class _Npz:
    """An uncompressed ``.npz``: the small entries, then ``frames`` streamed, ``meta`` last."""

    def __init__(self, path: Path, shape: tuple[int, int, int], extra: dict[str, Any]) -> None:
        self.archive = zipfile.ZipFile(path, "w", zipfile.ZIP_STORED, allowZip64=True)
        for key, value in extra.items():
            self._entry(key, np.asarray(value))
        self.stream = self.archive.open("frames.npy", "w", force_zip64=True)
        header = {"descr": "<f4", "fortran_order": False, "shape": shape}
        np.lib.format.write_array_header_1_0(self.stream, header)

    def _entry(self, key: str, value: np.ndarray) -> None:
        with self.archive.open(key + ".npy", "w", force_zip64=True) as handle:
            np.lib.format.write_array(handle, value, allow_pickle=False)

    def write(self, chunk: np.ndarray) -> None:
        self.stream.write(np.ascontiguousarray(chunk, dtype="<f4").tobytes())

    def finish(self, meta: str) -> None:
        self.stream.close()
        self._entry("meta", np.asarray(meta))
        self.archive.close()

    def abort(self) -> None:
        self.stream.close()  # the archive refuses to close over an open entry (and would hide the error)
        self.archive.close()


class _Hdf5:
    """HDF5: ``frames`` chunked by frame, ``t``; ``dx``, ``unit``, ``t_resolution`` on ``frames``."""

    def __init__(self, path: Path, shape: tuple[int, int, int], extra: dict[str, Any]) -> None:
        try:
            import h5py
        except ImportError as err:
            raise ImportError("writing HDF5 needs h5py: pip install anra_torch[formats]") from err
        self.file = h5py.File(path, "w")
        self.frames = self.file.create_dataset("frames", shape, dtype="<f4", chunks=(1, *shape[1:]))
        self.file.create_dataset("t", data=extra.pop("t"))
        self.frames.attrs.update(extra)
        self.done = 0

    def write(self, chunk: np.ndarray) -> None:
        self.frames[self.done : self.done + len(chunk)] = chunk
        self.done += len(chunk)

    def finish(self, meta: str) -> None:
        self.file.attrs["meta"] = meta
        self.file.close()

    def abort(self) -> None:
        self.file.close()


class _Tiff:
    """A BigTIFF, one float32 page per frame; its JSON description holds ``t``, ``dx``, ``unit``, ``meta``."""

    def __init__(self, path: Path, shape: tuple[int, int, int], extra: dict[str, Any]) -> None:
        try:
            import tifffile
        except ImportError as err:
            raise ImportError("writing TIFF needs tifffile: pip install anra_torch[formats]") from err
        self.shape, self.extra = shape, {k: np.asarray(v).tolist() for k, v in extra.items()}
        self.writer = tifffile.TiffWriter(path, bigtiff=True)
        self.first = True

    def write(self, chunk: np.ndarray) -> None:
        for frame in np.asarray(chunk, dtype="<f4"):  # one page per frame is the format
            self.writer.write(frame, contiguous=True, metadata={"meta": ""} if self.first else None)
            self.first = False

    def finish(self, meta: str) -> None:
        self.writer.overwrite_description(json.dumps({"shape": list(self.shape), **self.extra, "meta": meta}))
        self.writer.close()

    def abort(self) -> None:
        self.writer.close()


WRITERS: dict[str, Callable[..., Any]] = {
    ".npz": _Npz,
    ".h5": _Hdf5,
    ".hdf5": _Hdf5,
    ".tif": _Tiff,
    ".tiff": _Tiff,
}
"""Output suffix -> writer: ``(path, shape, extra)`` with ``write(chunk)``, ``finish(meta)`` and ``abort()``;
each writes the temporary file :func:`~anra_torch.checks.atomic_output` gives it (the rename is not its
business)."""


# ------------------------------------------------------------------------------------------ command
def _span(text: str | None, n: int) -> tuple[int, int]:
    """``--frames START:STOP`` as ``[start, stop)`` of ``n`` frames."""
    if text is None:
        return 0, n
    try:
        first, last = (int(v) if v.strip() else None for v in text.split(":"))
    except ValueError:
        raise ValueError(
            f"--frames must be START:STOP (integers, either may be empty), got {text!r}"
        ) from None
    start, stop, _ = slice(first, last).indices(n)
    if stop <= start:
        raise ValueError(f"--frames must keep at least one of the {n} frames, got {text!r}")
    return start, stop


def _region(text: str | None, h: int, w: int) -> tuple[int, int, int, int]:
    if text is None:
        return 0, 0, w, h
    x0, y0, width, height = parse_roi(text)
    if x0 + width > w or y0 + height > h:
        raise ValueError(f"--roi {text} (X0,Y0,W,H px) does not fit in the {w} x {h} px frame")
    return x0, y0, width, height


def _flags(times: np.ndarray, start: int) -> list[str]:
    steps = np.diff(times)
    bad = np.flatnonzero(steps <= 0)
    if not bad.size:
        return []
    return [
        f"times repeat or go backwards at {bad.size} frames (first at frame {start + bad[0] + 1}: "
        f"{times[bad[0] + 1]:.3f} s after {times[bad[0]]:.3f} s); written as measured, not reordered"
    ]


def run(args: argparse.Namespace) -> int:
    """Run ``anra convert`` with the parsed ``args``; returns the exit status (0 ok, 2 error)."""
    out = check_output(args.out, [args.video], name="-o")
    writer_of = WRITERS.get(out.suffix.lower())
    if writer_of is None:
        raise ValueError(f"-o must end in one of {', '.join(WRITERS)}, got {out.name!r}")
    frames, t, dx, meta = _source(args)
    n, h, w = frames.shape
    start, stop = _span(args.frames, n)
    x0, y0, width, height = _region(args.roi, h, w)
    times = t[start:stop] - t[start]
    warnings = [*meta.pop("input_warnings", []), *_flags(times, start)]
    extra: dict[str, Any] = {"t": times, "unit": meta.get("unit", "data units")}
    if dx is not None:
        extra["dx"] = float(dx)
    if "t_resolution" in meta:
        extra["t_resolution"] = float(meta["t_resolution"])
    step = max(1, math.ceil(int(args.chunk_values) / (h * w)))
    with atomic_output(out) as temp:
        writer = writer_of(temp, (stop - start, height, width), dict(extra))
        try:
            bad = _stream(frames, writer, (start, stop, step), (y0, height, x0, width))
            if bad == (stop - start) * height * width:
                raise ValueError(
                    f"{args.video}: no finite value in the frames to write ({bad} samples not finite, or "
                    "counts outside the Planck range); nothing written"
                )
            if bad:
                warnings.append(
                    f"{bad} samples masked (not finite in the file, beyond float32, or counts outside the "
                    "Planck range)"
                )
            record = {
                "source": str(args.video),
                **meta,
                "frames": [start, stop],
                "t_first_s": float(t[start]),
            }
            record.update(roi=[x0, y0, width, height] if args.roi else None, warnings=warnings)
            plain = json.loads(json.dumps(record, default=_plain))  # numpy values as JSON's own first
            writer.finish(json_line(plain))  # strict JSON: a non-finite value (a damaged header's) is null
        except BaseException:
            writer.abort()
            raise
    for line in warnings:
        print(f"anra: warning: {line}", file=sys.stderr)
    print(f"{out}: {stop - start} frames of {height} x {width} px over {times[-1]:.3f} s ({extra['unit']})")
    return 0


def _stream(frames: Any, writer: Any, span: tuple[int, int, int], region: tuple[int, int, int, int]) -> int:
    """Frames ``start .. stop - 1`` (``span``: start, stop, frames per chunk) of ``region`` (y0, height, x0,
    width) written chunk by chunk as float32, every sample that is not finite there as NaN; returns how
    many."""
    start, stop, step = span
    y0, height, x0, width = region
    bad = 0
    with tqdm(total=stop - start, unit="frame", file=sys.stderr, disable=not sys.stderr.isatty()) as bar:
        for a in range(start, stop, step):
            with np.errstate(over="ignore", invalid="ignore"):  # beyond float32: counted, written as NaN
                block = np.asarray(frames[a : min(a + step, stop)], dtype=np.float32)
            block = np.array(block[:, y0 : y0 + height, x0 : x0 + width])
            lost = ~np.isfinite(block)
            block[lost] = np.nan
            bad += int(lost.sum())
            writer.write(block)
            bar.update(len(block))
    return bad
