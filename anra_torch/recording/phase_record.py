"""What the diagnosis of one phase of a recording holds (:class:`PhaseDiagnosis`, the ``"phases"`` element
of ``anra diagnose --json``), its gains and the flags and warnings any family of models sets on it."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from torch import Tensor

from anra_torch.checks import implausible_diffusivity
from anra_torch.effects import EFFECTS
from anra_torch.forecast import GainResult
from anra_torch.recording.records import phase_head
from anra_torch.video import Phase

__all__ = ["PhaseDiagnosis", "flag_implausible", "gain_of", "implausible"]


@dataclass
class PhaseDiagnosis:
    """One phase of a recording and what its analysis found.

    Attributes:
        phase: the :class:`~anra_torch.video.Phase` (kind, frames, times).
        family: ``"balance"`` (the filters fit), ``"small_box"`` or ``"none"`` (not analysed).
        diffusivity: the plain model's ``a`` in mm^2/s (None when unresolved or not analysed).
        flags: what qualifies the diffusivity (``"unresolved"``, ``"not_significant"``: within 3
            standard errors of 0, ``"negative"``, ``"implausible"``: outside every known material).
        diffusivity_std_error: its standard error in mm^2/s, where known (the small-box fit's).
        diffusivity_bound: the lower bound on ``a`` in mm^2/s an unresolved diffusivity implies.
        base_rmse: the plain model's held-out RMSE in data units.
        model: the extension chosen on the inner split (``parametric``, a name in :data:`SOURCE_MAPS`,
            ``loss``, ``quasi_steady``; ``plain`` when the diagnosed extension cannot be simulated and no
            map could be compared).
        extended_rmse: the chosen extension's held-out RMSE.
        gain: ``1 - extended_rmse / base_rmse``.
        noise_floor: a perfect model's RMSE at the same scale.
        effects: the named causes, ``{"name", "params", "gain"}``.
        candidates: per candidate extension, its validation error inside the fit frames (``validation_rmse``:
            its RMSE over the plain model's, averaged over the inner splits) and its held-out gain
            (``gain``, reported after the choice, never used for it).
        reason: why the phase was not analysed, else None.
        result: the balance family's :class:`~anra_torch.forecast.GainResult`.
        forecasts: the held-out frames as ``"measured"``, ``"plain"`` and ``"extended"`` (the chosen
            model) forecasts, at the scale their RMSE was taken on (for figures); None when not analysed.
        warnings: signs of a missing term: an effect whose own held-out gain is not positive, or placed
            outside the field of view (:func:`implausible`); a weak signal.
        signal_to_noise: how much the fit frames change, in noise sds
            (:func:`~anra_torch.forecast.signal_to_noise`; the balance family only): under
            :data:`~anra_torch.forecast.WEAK_SIGNAL` the signal is weak, and a warning says so.

    Shape:
        each of ``forecasts`` ``(K, H, W)``.
    """

    phase: Phase
    family: str
    diffusivity: float | None = None
    flags: list[str] = field(default_factory=list)
    diffusivity_std_error: float | None = None
    diffusivity_bound: float | None = None
    base_rmse: float | None = None
    model: str | None = None
    extended_rmse: float | None = None
    gain: float | None = None
    noise_floor: float | None = None
    effects: list[dict[str, Any]] = field(default_factory=list)
    candidates: dict[str, dict[str, float | None]] = field(default_factory=dict)
    reason: str | None = None
    result: GainResult | None = None
    forecasts: dict[str, Tensor] | None = None
    warnings: list[str] = field(default_factory=list)
    signal_to_noise: float | None = None

    def to_record(self) -> dict[str, Any]:
        """The phase as a JSON-ready dict (the ``"phases"`` element of ``anra diagnose --json``)."""
        record: dict[str, Any] = {
            **phase_head(self.phase),
            "analysed": self.reason is None,
            "family": self.family,
            "base": {"diffusivity": self.diffusivity, "prediction_rmse": self.base_rmse},
            "effects": self.effects,
            "model": self.model,
            "extended_rmse": self.extended_rmse,
            "gain": self.gain,
            "noise_floor": self.noise_floor,
            "candidates": self.candidates,
            "warnings": list(self.warnings),
        }
        if self.flags:
            record["base"]["flags"] = list(self.flags)
        if self.diffusivity_std_error is not None:
            record["base"]["std_error"] = self.diffusivity_std_error
        if self.diffusivity_bound is not None:
            record["base"]["diffusivity_lower_bound"] = self.diffusivity_bound
        if self.signal_to_noise is not None:
            record["signal_to_noise"] = self.signal_to_noise
        if self.reason is not None:
            record["reason"] = self.reason
        return record


def gain_of(rmse: float, base: float) -> float:
    """``1 - rmse / base`` (0 without a base error)."""
    return 1.0 - rmse / base if base > 0 else 0.0


def flag_implausible(diagnosis: PhaseDiagnosis, dt: float, dx: float) -> None:
    """Flag (``"implausible"``, with a warning line) a diffusivity outside every known material
    (:data:`~anra_torch.checks.PLAUSIBLE_DIFFUSIVITY`) that no other flag already qualifies: a small box whose
    significant ``a`` of 4e-4 mm^2/s describes the fit, not the material."""
    a = diagnosis.diffusivity
    outside = None if a is None else implausible_diffusivity(a, dt=dt, dx=dx)
    if outside and not {"unresolved", "not_significant"} & set(diagnosis.flags):
        diagnosis.flags.append("implausible")
        diagnosis.warnings.append(outside)


def implausible(effects: list[dict[str, Any]], height: float, width: float) -> list[str]:
    """Signs of a missing term among the named ``effects`` of a ``height`` x ``width`` mm frame: an own
    held-out gain of zero or below, or a position (the effect's ``positions``, mm) outside the frame."""
    out = []
    for e in effects:
        name, params = e["name"], e["params"]
        if e["gain"] is not None and not e["gain"] > 0:
            out.append(
                f"{name}: its own held-out gain is {e['gain']:.3g} (not positive): it fits the diagnosed "
                "frames but does not forecast; a sign of a term the model is missing"
            )
        for kx, ky in EFFECTS[name].positions:
            x, y = params.get(kx, 0.0), params.get(ky, 0.0)
            if not (0 <= x <= width and 0 <= y <= height):
                out.append(
                    f"{name}: {kx}, {ky} = ({x:.3g}, {y:.3g}) mm lies outside the {width:.3g} x "
                    f"{height:.3g} mm field of view; a sign of a term the model is missing"
                )
    return out
