"""Frame-by-frame ANRA: a ring buffer of filtered frames, causal time filters, an estimate after every frame.

The spatial filters commute with the time filter, so each frame is filtered in space once when it arrives
and kept in a ring buffer of ``L`` frames; the time filter is an ``L``-term sum over the buffer, causal
(the estimate applies ``L - 1 - centre`` frames back, :attr:`TimeDerivative.delay`), and only the running
sums of the offline estimator's frame means are kept: memory is ``O(L H W)`` whatever the length of the
video. The derivation: ``docs/architecture.md`` ("The estimator", Streaming).

:class:`StreamingEstimator` takes one frame ``(H, W)`` or a block ``(n, H, W)`` at a time; on the same frames,
with the same fixed configuration (one smoothing sigma, a known ``noise_sd``), its diffusivity equals the
offline estimator's up to float rounding. :func:`estimate_long` feeds a long video (any array that can be
sliced, e.g. a ``numpy.load(..., mmap_mode="r")`` memmap) through it in chunks, so peak memory does not grow
with the number of frames.

Differences from the offline estimator, by design: one smoothing sigma (no automatic choice, which needs the
whole video), the noise level from the first ``noise_frames`` frames when not given, no standard error and no
dead-pixel detection (constant pixels are only recognisable once the video is over); non-finite pixels are
masked (with their filter support) exactly as offline.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor
from tqdm.auto import tqdm

from anra_torch.balance import MatchedFilters, Moments, accumulate, estimate_noise_sd
from anra_torch.checks import own_tensor
from anra_torch.video import LazyFrames

__all__ = ["NpyFrames", "StreamingEstimate", "StreamingEstimator", "estimate_long"]

NpyFrames = LazyFrames  # the name this module gave it first

_NAMES = ("U", "L")


@dataclass(frozen=True)
class StreamingEstimate:
    """The estimate after the frames seen so far.

    Attributes:
        diffusivity: global ``a`` in mm^2/s over every complete window so far; NaN exactly when ``ready`` is
            False (the reason in ``message``).
        per_frame: ``a`` of the newest window alone in mm^2/s, NaN when not ready.
        frames_seen: frames pushed so far.
        windows: complete time windows (``frames_seen - L + 1``, at least 0).
        noise_sd: noise sd used in data units, NaN before it is known.
        reliability: fraction of the regressor energy that is signal (1 is noiseless).
        time: instant (s after the first frame) the newest window's derivative applies to.
        ready: True once a diffusivity is available.
        message: why there is none yet ("" when ready).
    """

    diffusivity: float
    per_frame: float
    frames_seen: int
    windows: int
    noise_sd: float
    reliability: float
    time: float
    ready: bool
    message: str


class StreamingEstimator:
    """ANRA diffusivity from a live stream of frames, one frame (or block) at a time.

    Args:
        dt: frame period in s.
        dx: pixel size in mm.
        smoothing: spatial Gaussian sigma in px (one value: the automatic choice needs the whole video).
        time_family: Holoborodko time family, as offline.
        time_length: time window length ``L`` in frames.
        laplacian_size: spatial kernel size, as offline.
        laplacian_family: ``"central"`` (offline lsq default) or ``"holoborodko"``.
        eiv_correction: subtract the noise variance/covariance (as offline).
        noise_sd: known noise sd in data units; None estimates it once from the first ``noise_frames``
            frames with :func:`anra_torch.balance.estimate_noise_sd`.
        noise_frames: frames used for that estimate (>= 5).
        dtype: computation dtype (float64 reproduces the offline float64 result; float32 is faster).

    Shape:
        :meth:`push` takes ``(H, W)`` or ``(n, H, W)``; every frame of a stream must have the same ``(H, W)``.

    Example:
        >>> from anra_torch.simulation import gaussian_blob
        >>> video = gaussian_blob(torch.arange(12) / 27.0, shape=(48, 48), dx=0.1, a=0.2, peak=3.0, sigma=1.0)
        >>> stream = StreamingEstimator(dt=1 / 27, dx=0.1, smoothing=1.0, noise_sd=0.0)
        >>> for frame in video:
        ...     est = stream.push(frame)
        >>> round(est.diffusivity, 3)
        0.2
    """

    def __init__(
        self,
        *,
        dt: float,
        dx: float,
        smoothing: float = 4.0,
        time_family: str = "smooth",
        time_length: int = 5,
        laplacian_size: int = 5,
        laplacian_family: str = "central",
        eiv_correction: bool = True,
        noise_sd: float | None = None,
        noise_frames: int = 16,
        dtype: torch.dtype = torch.float32,
    ) -> None:
        for name, value, unit in (("dt", dt, "s"), ("dx", dx, "mm")):
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive finite number in {unit}, got {value!r}")
        if noise_sd is not None and not (math.isfinite(noise_sd) and noise_sd >= 0):
            raise ValueError(f"noise_sd must be a finite number >= 0 (data units), got {noise_sd!r}")
        if not (isinstance(noise_frames, int) and noise_frames >= 5):
            raise ValueError(f"noise_frames must be an integer >= 5, got {noise_frames!r}")
        if dtype not in (torch.float32, torch.float64):
            raise ValueError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        self.dt, self.dx, self.dtype = float(dt), float(dx), dtype
        self.filters = MatchedFilters(
            smoothing,
            time_family=time_family,
            time_length=time_length,
            laplacian_size=laplacian_size,
            laplacian_family=laplacian_family,
        )
        self.time, self.smoother, self.laplacian = (
            self.filters.time,
            self.filters.smoother,
            self.filters.laplacian,
        )
        self.eiv_correction = eiv_correction
        self.noise_frames = noise_frames
        self._taps = (self.time.taps / self.dt).tolist()
        self._pair = self.time.pair.tolist()
        self.margin = self.filters.margin
        self._given_noise = noise_sd
        self.reset()

    def reset(self) -> None:
        """Forget every frame (start a new stream with the same configuration)."""
        self._rate_ring: list[Tensor] = []  # P G T_j, newest last, at most L
        self._lap_ring: list[Tensor] = []  # Lap G T_j / dx^2
        self._mask_ring: list[Tensor | None] = []  # valid output pixels of frame j (None: all)
        self._noise_buffer: list[Tensor] = []
        self._shape: tuple[int, int] | None = None
        self._offset: Tensor | None = None
        self.frames_seen = 0
        self.windows = 0
        self._sums: Moments | None = None  # of (U, Lap) over windows, each window's pixels weighted 1/count
        self._last = (math.nan, math.nan)  # newest window's (mean U Lap, mean Lap^2)
        self.noise_sd = math.nan if self._given_noise is None else float(self._given_noise)

    # ----------------------------------------------------------------------------------- filtering
    def _check(self, frames: Any) -> Tensor:
        block = own_tensor(frames)
        if block.dtype == torch.bool or block.is_complex():
            raise TypeError(f"frames must hold real temperatures, got dtype {block.dtype}")
        if block.ndim == 2:
            block = block.unsqueeze(0)
        if block.ndim != 3:
            raise ValueError(f"frames must have shape (H, W) or (n, H, W), got {tuple(block.shape)}")
        h, w = block.shape[-2:]
        if self._shape is None:
            need = 2 * self.margin + 1
            if min(h, w) < need:
                raise ValueError(
                    f"frames must be at least {need} x {need} px for these filters, got {h} x {w}"
                )
            self._shape = (h, w)
        elif (h, w) != self._shape:
            raise ValueError(
                f"frames must keep the stream's size {self._shape[0]} x {self._shape[1]}, got {h} x {w}"
            )
        return block.to(self.dtype)

    def _valid(self, finite: Tensor) -> Tensor:
        """Output pixels whose whole spatial support is finite, ``(n, H'', W'')``."""
        k = 2 * self.margin + 1
        bad = F.max_pool2d((~finite).to(torch.float32).unsqueeze(1), k, stride=1).squeeze(1)
        return bad == 0

    def _spatial(self, block: Tensor) -> tuple[Tensor, Tensor, Tensor | None]:
        finite = torch.isfinite(block)
        mask = None
        if not bool(finite.all()):
            mask = self._valid(finite)
            block = torch.where(finite, block, torch.zeros_like(block))
        smooth = self.smoother(block)
        return self.laplacian.partner(smooth), self.laplacian(smooth, self.dx), mask

    # -------------------------------------------------------------------------------------- update
    def push(self, frames: Any) -> StreamingEstimate:
        """Add one frame ``(H, W)`` or a block ``(n, H, W)`` (oldest first); return the current estimate.

        Raises:
            ValueError: wrong shape, a size change within the stream, frames smaller than the filters.
            TypeError: non-numeric frames.
        """
        block = self._check(frames)
        if self._offset is None:  # a constant offset keeps float32 precise on e.g. 300 K scenes
            first = block[0][torch.isfinite(block[0])]
            self._offset = first.mean() if first.numel() else block.new_zeros(())
        block = block - self._offset
        if math.isnan(self.noise_sd) and len(self._noise_buffer) < self.noise_frames:
            self._noise_buffer.extend(block[: self.noise_frames - len(self._noise_buffer)])
            if len(self._noise_buffer) >= self.noise_frames:
                self.noise_sd = float(estimate_noise_sd(torch.stack(self._noise_buffer)))
                self._noise_buffer = []
        rate, lap, mask = self._spatial(block)
        length = self.time.length
        for j in range(block.shape[0]):  # per frame only list bookkeeping; the maths below is batched
            self._rate_ring.append(rate[j])
            self._lap_ring.append(lap[j])
            self._mask_ring.append(None if mask is None else mask[j])
        # Windows completed by this block: those ending at each new frame with L frames available.
        total = len(self._rate_ring)
        n_new = max(0, total - length + 1)
        if n_new:
            rates = torch.stack(self._rate_ring)
            laps = torch.stack(self._lap_ring)
            u = sum(tap * rates[i : i + n_new] for i, tap in enumerate(self._taps) if tap != 0.0)
            lp = sum(tap * laps[i : i + n_new] for i, tap in enumerate(self._pair) if tap != 0.0)
            weights = None
            if any(m is not None for m in self._mask_ring):
                masks = torch.stack(
                    [torch.ones_like(laps[0], dtype=torch.bool) if m is None else m for m in self._mask_ring]
                )
                window = masks[0:n_new].clone()
                for i in range(1, length):
                    window &= masks[i : i + n_new]
                counts = window.sum((-2, -1), keepdim=True).clamp_min(1)
                weights = window.to(u.dtype) / counts
            terms = {"U": u, "L": lp}
            windows = accumulate(terms, _NAMES, dims=(-2, -1), weights=weights)  # (n_new, 2, 2)
            if weights is None:  # frame means
                windows = windows.map(lambda x: x / (u.shape[-2] * u.shape[-1]))
            windows = windows.map(lambda x: x.double())
            self._last = (float(windows.raw[-1, 0, 1]), float(windows.raw[-1, 1, 1]))
            total = windows.map(lambda x: x.sum(0))
            self._sums = total if self._sums is None else self._sums + total
            self.windows += n_new
        keep = length - 1
        self._rate_ring = self._rate_ring[-keep:] if keep else []
        self._lap_ring = self._lap_ring[-keep:] if keep else []
        self._mask_ring = self._mask_ring[-keep:] if keep else []
        self.frames_seen += block.shape[0]
        return self.estimate()

    def estimate(self) -> StreamingEstimate:
        """The estimate from the frames pushed so far (see :class:`StreamingEstimate`)."""
        when = (self.windows - 1 + self.time.centre) * self.dt if self.windows else math.nan
        base = {
            "frames_seen": self.frames_seen,
            "windows": self.windows,
            "noise_sd": self.noise_sd,
            "time": when,
        }
        if self.windows == 0:
            need = self.time.length
            return StreamingEstimate(
                math.nan,
                math.nan,
                reliability=math.nan,
                ready=False,
                message=f"need {need} frames for the time filter, got {self.frames_seen}",
                **base,
            )
        if math.isnan(self.noise_sd) and self.eiv_correction:
            return StreamingEstimate(
                math.nan,
                math.nan,
                reliability=math.nan,
                ready=False,
                message=f"noise level not known yet: estimated after {self.noise_frames} frames, "
                f"got {self.frames_seen}",
                **base,
            )
        var = cov = 0.0
        if self.eiv_correction:
            covariance = self.filters.noise_covariance(_NAMES, self.noise_sd**2, self.dt, self.dx)
            var, cov = float(covariance[1, 1]), float(covariance[0, 1])
        assert self._sums is not None
        sum_ul, sum_ll = float(self._sums.raw[0, 1]), float(self._sums.raw[1, 1])
        num = sum_ul - self.windows * cov
        den = sum_ll - self.windows * var
        reliability = den / sum_ll if sum_ll > 0 else 0.0
        if not den > 0:
            return StreamingEstimate(
                math.nan,
                math.nan,
                reliability=reliability,
                ready=False,
                message="no thermal activity above the noise yet (Laplacian energy within the noise)",
                **base,
            )
        last_den = self._last[1] - var
        per_frame = (self._last[0] - cov) / last_den if last_den > 0 else math.nan
        return StreamingEstimate(
            num / den, per_frame, reliability=reliability, ready=True, message="", **base
        )


def _chunks(frames: Any, chunk: int) -> Iterator[Any]:
    for start in range(0, frames.shape[0], chunk):
        yield frames[start : start + chunk]


def estimate_long(
    frames: Any,
    dt: float,
    dx: float,
    *,
    chunk: int = 64,
    progress: bool = False,
    **options: Any,
) -> StreamingEstimate:
    """Diffusivity of a long video processed in chunks of frames (memory independent of its length).

    Args:
        frames: anything with ``shape`` ``(T, H, W)`` that slices along T into arrays or tensors, e.g.
            :class:`~anra_torch.video.LazyFrames` (a ``.npy`` file read chunk by chunk), an HDF5
            dataset, a tensor; only one chunk at a time is converted and filtered.
        dt: frame period in s.
        dx: pixel size in mm.
        chunk: frames per chunk, >= 1.
        progress: show a tqdm progress bar.
        **options: :class:`StreamingEstimator` options (``smoothing``, ``noise_sd``, ``dtype``, ...).

    Returns:
        :class:`StreamingEstimate` after the last frame.

    Raises:
        ValueError: ``frames`` without a ``(T, H, W)`` shape, ``chunk`` < 1, or the estimator's errors.

    Shape:
        ``frames`` ``(T, H, W)``.
    """
    shape = tuple(getattr(frames, "shape", ()))
    if len(shape) != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {shape}")
    if not (isinstance(chunk, int) and chunk >= 1):
        raise ValueError(f"chunk must be an integer >= 1 (frames), got {chunk!r}")
    stream = StreamingEstimator(dt=dt, dx=dx, **options)

    with tqdm(total=shape[0], unit="frame", desc="anra long video", disable=not progress) as bar:
        for block in _chunks(frames, chunk):
            stream.push(block if isinstance(block, Tensor) else torch.from_numpy(np.array(block)))
            bar.update(block.shape[0])
    return stream.estimate()
