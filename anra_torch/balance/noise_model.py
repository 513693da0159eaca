"""The noise model of the balance: how sensor noise of a measured level and correlation propagates into
the balanced terms and the estimates (:class:`NoiseModel`)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor

from anra_torch.layers import correlate1d

__all__ = ["NoiseModel"]

_MODEL_ERROR = 0.1  # relative error of a measured correlated or static noise variance


class NoiseModel:
    """Sensor noise of one video: its level, its correlation in time and space, as measured.

    The covariance kernel is ``C = sd^2 rho_t(tau) rho_s(dy) rho_s(dx)``, plus a white component
    ``white_sd^2`` beside it, plus a static part; a linear statistic ``<x, A(frames)>`` has the variance
    ``<A^T x, C A^T x>``, :meth:`quadratic` of the pushed-back lever ``A^T x``. How it propagates:
    ``docs/results/artefacts.md``, section "How the noise propagates".

    Args:
        sd: standard deviation per sample of the correlated noise in the data's units, a number or, for
            white noise only, ``(B,)``.
        time_corr: ``rho_t(1), rho_t(2), ...`` with ``rho_t(0) = 1``; empty for no correlation in time.
        space_length: Gaussian correlation length in px; 0 for none.
        white_sd: sd of an uncorrelated component beside the correlated one, in the data's units.
        static_sd, column_sd, row_sd: sds of a fixed pattern per pixel, per column and per row.
        variance_error: the relative error of the model's variance; None takes that of a measured model,
            :attr:`variance_error`; 0 for a model known exactly, such as a planted one.

    Shape:
        :meth:`quadratic` ``(P, T, H, W) -> (P, P)``, or ``(P, N)`` rows for white noise.
    """

    def __init__(
        self,
        sd: float | Tensor,
        *,
        time_corr: tuple[float, ...] = (),
        space_length: float = 0.0,
        white_sd: float = 0.0,
        static_sd: float = 0.0,
        column_sd: float = 0.0,
        row_sd: float = 0.0,
        variance_error: float | None = None,
    ) -> None:
        self.sd = sd
        self._variance_error = variance_error
        self.time_corr = tuple(float(r) for r in time_corr)
        self.space_length = float(space_length)
        self.white_sd = float(white_sd)
        self.static_sd, self.column_sd, self.row_sd = float(static_sd), float(column_sd), float(row_sd)

    @property
    def static(self) -> bool:
        """Whether the noise has a static part: a fixed pattern of the sensor."""
        return bool(self.static_sd or self.column_sd or self.row_sd)

    def without_static(self) -> NoiseModel:
        """This model without its static part: what a balance with per-pixel fixed effects sees."""
        return NoiseModel(
            self.sd,
            time_corr=self.time_corr,
            space_length=self.space_length,
            white_sd=self.white_sd,
            variance_error=self._variance_error,
        )

    @property
    def white(self) -> bool:
        """Whether the noise is uncorrelated in time and space, with no static part."""
        return not self.time_corr and self.space_length == 0.0 and not self.static and not self.white_sd

    @property
    def variance_error(self) -> float:
        """Relative error of the measured variance that a correction by it carries: 0 for white noise, 0.1
        for a correlated or static model, or the value given to the constructor. Why these values:
        ``docs/results/artefacts.md``, section "How the noise propagates"."""
        if self._variance_error is not None:
            return float(self._variance_error)
        return 0.0 if self.white else _MODEL_ERROR

    @property
    def variance(self) -> float | Tensor:
        """``sd^2`` in the data's units squared."""
        return self.sd**2

    def time_kernel(self) -> Tensor:
        """``rho_t(tau)`` for ``tau = -m .. m``, float64."""
        half = torch.tensor(self.time_corr, dtype=torch.float64, device="cpu")
        return torch.cat([half.flip(0), torch.ones(1, dtype=torch.float64, device="cpu"), half])

    def space_kernel(self) -> Tensor:
        """``rho_s(d)`` for ``d = -r .. r`` px with ``r`` = 4 lengths, float64."""
        if self.space_length == 0.0:
            return torch.ones(1, dtype=torch.float64, device="cpu")
        r = max(1, math.ceil(4.0 * self.space_length))
        d = torch.arange(-r, r + 1, dtype=torch.float64, device="cpu")
        return torch.exp(-(d**2) / (2.0 * self.space_length**2))

    def correlate(self, x: Tensor) -> Tensor:
        """``C x / sd^2``: ``x`` correlated by the noise's covariance kernel, same size ('same' padding).

        The static part (a fixed pattern: per pixel, per column and per row, constant in time) adds
        ``static_sd^2`` times ``x`` summed over time, ``column_sd^2`` times ``x`` summed over time and rows,
        and ``row_sd^2`` times ``x`` summed over time and columns, each spread back over what it summed.

        Shape:
            ``(..., T, H, W)`` -> the same.
        """
        out = x
        for dim, taps in ((-3, self.time_kernel()), (-2, self.space_kernel()), (-1, self.space_kernel())):
            if taps.numel() == 1:
                continue
            pad = taps.numel() // 2  # zero-padded: the same size (the kernel is symmetric)
            out = correlate1d(F.pad(out, [0, 0] * (-dim - 1) + [pad, pad]), taps.tolist(), dim)
        variance = max(float(self.variance), 1e-300)
        if self.white_sd and not self.white:
            out = out + (self.white_sd**2 / variance) * x
        if self.static:
            for part, dims in ((self.static_sd, (-3,)), (self.column_sd, (-3, -2)), (self.row_sd, (-3, -1))):
                if part:
                    out = out + (part**2 / variance) * x.sum(dims, keepdim=True).expand_as(x)
        return out

    def quadratic(self, backs: Tensor) -> Tensor:
        """``Cov(<b_i, n>, <b_j, n>) = <b_i, C b_j>`` for pushed-back levers ``b`` (first dim)."""
        flat = backs.reshape(backs.shape[0], -1)
        if self.white:
            return self.variance * (flat @ flat.T)
        return self.variance * (flat @ self.correlate(backs).reshape(backs.shape[0], -1).T)

    def describe(self) -> dict:
        """The JSON ``"noise"`` object; its keys: ``docs/reference/outputs.md``, section
        ``anra diagnose --json``: ``noise``."""
        sd = self.sd if not isinstance(self.sd, Tensor) else float(self.sd.reshape(-1)[0])
        return {
            "sd": float(sd),
            "time_correlation": list(self.time_corr),
            "space_length_px": self.space_length,
            "white_sd": self.white_sd,
            "static_sd": self.static_sd,
            "column_sd": self.column_sd,
            "row_sd": self.row_sd,
            "white": self.white,
        }
