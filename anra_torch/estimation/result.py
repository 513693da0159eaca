"""What :class:`~anra_torch.estimation.ANRAEstimator` returns: one diffusivity per video with its standard
error, flags and the measured noise and artefacts, and the record ``anra estimate --json`` prints."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

__all__ = ["ANRAResult", "concat_results"]


def concat_results(parts: list[ANRAResult]) -> ANRAResult:
    """Results of consecutive slices of a batch as one batched result."""
    changes = {}
    for f in fields(ANRAResult):
        values = [getattr(p, f.name) for p in parts]
        if isinstance(values[0], tuple):  # messages, warnings, noise, artefacts: one entry per video
            changes[f.name] = tuple(m for v in values for m in v)
        elif values[0] is not None:
            changes[f.name] = torch.cat(values)
    return replace(parts[0], **changes)


@dataclass(frozen=True)
class ANRAResult:
    """Output of :class:`ANRAEstimator`: batched with a leading ``B``; a single video drops it.

    Attributes:
        diffusivity: global ``a`` per video in mm^2/s, the units of dx^2/dt, ``(B,)``; NaN only where
            ``valid`` is False, with the reason in ``messages``.
        std_error: standard error of ``diffusivity`` propagated from the estimated white noise, ``(B,)``.
        per_frame: ``a[k]`` per frame, ``(B, K)`` with ``K = T - L + 1``.
        frame_times: the instant in s after the first frame each ``a[k]`` applies to, ``(B, K)``.
        noise_sd: noise standard deviation used, in the data's units, ``(B,)``.
        smoothing: spatial Gaussian sigma used in px, ``(B,)``.
        reliability: fraction of the regressor energy that is signal, not noise; 1 is noiseless; ``(B,)``.
        explained: share of the weighted energy of ``dT/dt`` above the noise that ``a Lap T`` explains, in
            [0, 1], ``(B,)``: the noise-corrected ``R^2`` of the plain heat equation. Below
            :data:`POOR_FIT` the estimate is flagged: a term the plain model misses dominates. NaN in
            ``"ratio"`` mode.
        valid: False for a video without measurable thermal activity, ``(B,)``.
        n_masked: number of pixel values masked, non-finite or dead elements constant in every frame
            while the scene changes, ``(B,)``.
        field: windowed diffusivity map aligned with the input frames, ``(B, H, W)``, or None; NaN where
            ``confidence == 0``, at the border the filters cannot reach and in windows without signal.
        confidence: reliability of each window in [0, 1], ``(B, H, W)``, or None.
        messages: one line per video: the reason when not valid, else empty; a valid video's flags are in
            ``warnings``.
        warnings: per video, the plausibility flags of a valid estimate from
            :func:`anra_torch.checks.diffusivity_warnings`: significantly negative, a source dominating, or
            outside every known material, with the likely unit mix-up of dt or dx; empty when none.
        noise: per video, the measured noise model as a record, see :meth:`NoiseModel.describe
            <anra_torch.balance.NoiseModel.describe>`.
        artefacts: per video, the camera artefacts found and what was done, see :meth:`Artefacts.to_record
            <anra_torch.balance.Artefacts.to_record>`.
    """

    diffusivity: Tensor
    std_error: Tensor
    per_frame: Tensor
    frame_times: Tensor
    noise_sd: Tensor
    smoothing: Tensor
    reliability: Tensor
    explained: Tensor
    valid: Tensor
    n_masked: Tensor
    field: Tensor | None
    confidence: Tensor | None
    messages: tuple[str, ...]
    warnings: tuple[tuple[str, ...], ...] = ()
    noise: tuple[dict, ...] = ()
    artefacts: tuple[dict, ...] = ()

    def unbatched(self) -> ANRAResult:
        """The same result with the batch dimension of size 1 removed."""
        changes = {
            f.name: getattr(self, f.name)[0]
            for f in fields(self)
            if isinstance(getattr(self, f.name), Tensor)
        }
        return replace(self, **changes)

    def to_record(self, index: int = 0, *, unit: str = "data units") -> dict[str, object]:
        """The numbers of one video as a JSON-ready record: ``anra estimate --json``, batch rows, reports.

        Args:
            index: the video in a batched result; 0 for an unbatched one.
            unit: the data's temperature unit, for ``noise_sd``.

        Returns:
            The diffusivity and its standard error in mm^2/s, None when not finite, the flags, the
            smoothing, the noise, the masked count, the artefacts and every value's unit. Every key:
            ``docs/reference/outputs.md``, section ``anra estimate --json``.

        Shape:
            Tensors ``(B,)`` or unbatched scalars; the record holds Python numbers.

        Raises:
            ValueError: ``index`` outside the batch.
        """
        size = self.diffusivity.shape[0] if self.diffusivity.ndim else 1
        if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < size:
            raise ValueError(f"index must be an integer in [0, {size}) for this result, got {index!r}")

        def pick(values: Tensor) -> Tensor:
            return values[index] if values.ndim else values

        def finite(values: Tensor) -> float | None:  # JSON has no NaN: no estimate is null
            value = pick(values)
            return float(value) if bool(torch.isfinite(value)) else None

        return {
            "diffusivity": finite(self.diffusivity),
            "std_error": finite(self.std_error),
            "valid": bool(pick(self.valid)),
            "message": self.messages[index],
            "warnings": list(self.warnings[index]) if index < len(self.warnings) else [],
            "smoothing_px": float(pick(self.smoothing)),
            "noise_sd": float(pick(self.noise_sd)),
            "reliability": float(pick(self.reliability)),
            "explained": finite(self.explained),
            "n_masked": int(pick(self.n_masked)),
            "units": {"diffusivity": "mm^2/s", "std_error": "mm^2/s", "smoothing_px": "px", "noise_sd": unit},
            "noise": self.noise[index] if index < len(self.noise) else None,
            "artefacts": self.artefacts[index] if index < len(self.artefacts) else None,
        }
