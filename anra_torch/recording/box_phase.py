"""The small-box family of a phase diagnosis: regions too small for the balance's filters (down to 3 x 3 px),
where the ``loss`` and ``quasi_steady`` models of :mod:`~anra_torch.estimation.small_box` compete on splits
inside the fit frames and are scored on the held-out frames."""

from __future__ import annotations

import math

from torch import Tensor

from anra_torch.estimation import fit_small_box, forecast_small_box, unresolved_bound
from anra_torch.forecast import split_index
from anra_torch.recording.phase_record import PhaseDiagnosis, flag_implausible, gain_of
from anra_torch.video import Phase

__all__ = ["BOX_HORIZON", "BOX_WINDOW", "INNER_ORIGINS", "small_box_phase"]

BOX_WINDOW = 100
"""Frames just before a split that a small-box model is fitted on (the most local of 100, 200 and 400)."""

BOX_HORIZON = 200
"""Held-out frames forecast at most by a small-box model."""


def _box_forecasts(frames: Tensor, dt: float, dx: float, split: int, horizon: int) -> dict[str, Tensor]:
    """Each small-box model, fitted on the :data:`BOX_WINDOW` frames up to ``split``, forecasting the
    ``horizon`` frames after it (and ``"measured"``, those frames)."""
    fit = frames[max(0, split - BOX_WINDOW) : split + 1]
    out = {"measured": frames[split + 1 : split + 1 + horizon]}
    for kind in ("plain", "loss", "quasi_steady"):
        out[kind] = forecast_small_box(fit_small_box(fit, dt, dx, kind), frames, dt, dx, split, horizon)
    return out


def _box_scores(frames: Tensor, dt: float, dx: float, split: int, horizon: int) -> dict[str, float]:
    """RMSE on the interior of the frames after ``split`` for each small-box model fitted just before it."""
    forecasts = _box_forecasts(frames, dt, dx, split, horizon)
    measured = forecasts.pop("measured")[:, 1:-1, 1:-1]
    return {k: float((p[:, 1:-1, 1:-1] - measured).pow(2).mean().sqrt()) for k, p in forecasts.items()}


INNER_ORIGINS = (0.5, 0.6, 0.7, 0.8)
"""Forecast origins inside the fit frames (fractions) at which the small-box models are validated."""


def _box_validation(fit: Tensor, dt: float, dx: float) -> dict[str, float]:
    """Each small-box model's validation error: its RMSE over the plain model's, averaged over forecasts
    from several origins inside the fit frames (:data:`INNER_ORIGINS`), each fitted on the frames before."""
    n = fit.shape[0]
    ratios: dict[str, list[float]] = {"loss": [], "quasi_steady": []}
    for fraction in INNER_ORIGINS:
        origin = split_index(n, fraction)
        scores = _box_scores(fit, dt, dx, origin, min(n - 1 - origin, BOX_HORIZON))
        for kind, values in ratios.items():
            values.append(scores[kind] / scores["plain"] if scores["plain"] > 0 else 1.0)
    return {kind: sum(values) / len(values) for kind, values in ratios.items()}


def small_box_phase(phase: Phase, part: Tensor, dt: float, dx: float, fit_fraction: float) -> PhaseDiagnosis:
    """The small-box family: ``loss`` against ``quasi_steady`` on the inner split, scored on the held-out."""
    if min(part.shape[1:]) < 3:
        raise ValueError(f"frames must be at least 3 x 3 px, got {part.shape[1]} x {part.shape[2]}")
    n = part.shape[0]
    split = split_index(n, fit_fraction)
    validation = _box_validation(part[: split + 1], dt, dx)
    forecasts = _box_forecasts(part, dt, dx, split, min(n - 1 - split, BOX_HORIZON))
    measured = forecasts["measured"][:, 1:-1, 1:-1]
    held = {
        k: float((p[:, 1:-1, 1:-1] - measured).pow(2).mean().sqrt())
        for k, p in forecasts.items()
        if k != "measured"
    }
    chosen = min(("loss", "quasi_steady"), key=validation.__getitem__)
    fit = part[max(0, split - BOX_WINDOW) : split + 1]
    plain = fit_small_box(fit, dt, dx, "plain")
    model = fit_small_box(fit, dt, dx, chosen)
    inner_part = part[:, 1:-1, 1:-1]
    noise = float((inner_part[1 : split + 1] - inner_part[:split]).std()) / math.sqrt(2)
    gain = gain_of(held[chosen], held["plain"])
    diagnosis = PhaseDiagnosis(
        phase,
        "small_box",
        diffusivity=plain.a,
        diffusivity_std_error=plain.a_std_error,
        base_rmse=held["plain"],
        model=chosen,
        extended_rmse=held[chosen],
        gain=gain,
        noise_floor=noise,
        candidates={
            k: {"validation_rmse": validation[k], "gain": gain_of(held[k], held["plain"])}
            for k in ("loss", "quasi_steady")
        },
        forecasts={
            "measured": forecasts["measured"],
            "plain": forecasts["plain"],
            "extended": forecasts[chosen],
        },
    )
    bound = unresolved_bound(fit, dt, dx)
    if bound is not None:
        diagnosis.diffusivity = diagnosis.diffusivity_std_error = None
        diagnosis.flags.append("unresolved")
        diagnosis.diffusivity_bound = bound
    elif plain.significant is False:  # within 3 standard errors of 0: the box hardly changes
        diagnosis.flags.append("not_significant")
    elif plain.a < 0:
        diagnosis.flags.append("negative")
    flag_implausible(diagnosis, dt, dx)
    if chosen == "quasi_steady":
        cause = "source"
    else:  # the sign of the loss model's non-diffusive rate at the split: net heating or net loss
        cause = (
            "source" if model.c - model.b * (float(part[split].mean()) - model.t_ref) > 0 else "linear_loss"
        )
    diagnosis.effects = [{"name": cause, "params": model.params(), "gain": gain}]
    return diagnosis
