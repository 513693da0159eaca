"""What :class:`~anra_torch.tissue.TissueFeatures` returns and writes: the map names and units
(:data:`MAPS`, :data:`DOSE_MAPS`), the gates of the ANRA maps' extremes (:data:`MIN_CONFIDENCE`,
:data:`MAX_LOSS_ERROR`), the maps with their summary (:class:`TissueFeatureMaps`), the ``.npz`` of one video
(:func:`save_feature_maps`) and the JSON's record of how the doses were computed (:func:`dose_record`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import atomic_output
from anra_torch.tissue.depth_features import DEPTH_MAPS, DepthFeatures
from anra_torch.tissue.dose import CEM43_R, GAS_CONSTANT, ArrheniusConstants

__all__ = [
    "DOSE_MAPS",
    "EXTREMES",
    "MAPS",
    "MAP_UNITS",
    "MAX_LOSS_ERROR",
    "MIN_CONFIDENCE",
    "TissueFeatureMaps",
    "dose_record",
    "save_feature_maps",
]

MIN_CONFIDENCE = 0.9
"""Windows with at least this estimator confidence, the signal fraction of their Laplacian energy, are
confident: the ANRA map extremes come from them."""
MAX_LOSS_ERROR = 0.1
"""A window's loss rate counts for the extremes when its standard error times the recorded span is at most
this: the loss over the record, ``b (T - 1) dt``, known to within 0.1."""

EXTREMES = {
    "diffusivity_max": f"windows with confidence >= {MIN_CONFIDENCE:g}",
    "loss_rate_max, source_max": f"windows with confidence >= {MIN_CONFIDENCE:g} whose loss rate's standard "
    f"error times the recorded span is <= {MAX_LOSS_ERROR:g}",
}
"""Over which windows the ANRA maps' maxima are taken: the JSON's ``extremes``."""

MAPS: tuple[str, ...] = (
    "peak_temperature",
    "time_above_43",
    "time_above_50",
    "time_above_60",
    "cem43_minutes",
    "omega",
    "heating_rate",
    "cooling_rate",
    "rtc_attention",
    "diffusivity",
    "confidence",
    "loss_rate",
    "source",
)
"""Maps of the default :class:`TissueFeatures`, one ``time_above_<C>`` per threshold."""

DOSE_MAPS: tuple[str, ...] = MAPS[:6]
"""The maps that need no spatial filter, for any frame size; the others need the estimator's filters to
fit."""

MAP_UNITS: dict[str, str] = {
    **{name: "mm" for name in DEPTH_MAPS},
    "peak_temperature": "C",
    "cem43_minutes": "min",
    "omega": "1",
    "heating_rate": "K/s",
    "cooling_rate": "K/s",
    "rtc_attention": "1",
    "diffusivity": "mm^2/s",
    "confidence": "1",
    "loss_rate": "1/s",
    "source": "K",
}
"""The unit of every map; the ``time_above_<C>`` maps are in s."""


@dataclass(frozen=True)
class TissueFeatureMaps:
    """Output of :class:`TissueFeatures`: batched with a leading ``B``; a single video drops it.

    Attributes:
        maps: name -> map ``(B, H, W)``, finite everywhere; the rate and ANRA maps only where they fit.
        summary: name -> per-video value ``(B,)``: ``<map>_max`` for every map, the ANRA maps' over
            confident windows only, NaN when there are none; ``damaged_fraction``, the share of pixels
            with ``omega >= 1``; ``n_masked``, the non-finite samples; with the ANRA maps also
            ``diffusivity_global`` in mm^2/s, NaN only when ``valid`` is False, and ``confident_fraction``
            and ``loss_confident_fraction``, the shares of pixels whose windows count for the extremes.
            The gates: ``docs/guides/tissue-damage.md``.
        units: name -> unit of every map and summary value.
        masked: non-finite samples per pixel, ``(B, H, W)``.
        valid: whether the estimator measured a diffusivity, ``(B,)``.
        messages: one line per video, "" when all went well.
        loss_rate_std_error: standard error of ``loss_rate`` in 1/s, inf where the window never cools,
            ``(B, H, W)``; None without the ANRA maps.
        absent: map name -> why it was not computed: frames too small or too few, no pixel size.
        depth: with ``TissueFeatures(depth=True)`` and a pixel size, the depth model's maps, profiles and
            parameters, a :class:`anra_torch.tissue.DepthFeatures` batched even for a single video. The
            :data:`anra_torch.tissue.DEPTH_MAPS` are also in ``maps``, NaN for a video without a usable
            fit, with the reason in ``messages``.
        cooling_diffusivity: ``a`` in mm^2/s, fitted with ``loss_rate`` on cooling frames where no source
            biases it.
    """

    maps: dict[str, Tensor]
    summary: dict[str, Tensor]
    units: dict[str, str]
    masked: Tensor
    valid: Tensor
    messages: tuple[str, ...]
    loss_rate_std_error: Tensor | None = None
    absent: dict[str, str] = field(default_factory=dict)
    depth: DepthFeatures | None = None
    cooling_diffusivity: Tensor | None = None

    def stack(self, names: Sequence[str] | None = None) -> Tensor:
        """The maps as channels in the order of ``names``, all maps when None.

        Shape:
            ``(B, F, H, W)``, or ``(F, H, W)`` unbatched.

        Raises:
            ValueError: a name that is not a computed map.
        """
        names = list(self.maps) if names is None else list(names)
        unknown = [n for n in names if n not in self.maps]
        if unknown:
            why = f" ({self.absent[unknown[0]]})" if unknown[0] in self.absent else ""
            raise ValueError(
                f"unknown feature map {unknown[0]!r}{why}; expected one of: {', '.join(self.maps)}"
            )
        return torch.stack([self.maps[n] for n in names], dim=-3)

    def unbatched(self) -> TissueFeatureMaps:
        """The same result with the batch dimension of size 1 removed."""
        optional = {k: getattr(self, k) for k in ("loss_rate_std_error", "cooling_diffusivity")}
        return replace(
            self,
            maps={k: v[0] for k, v in self.maps.items()},
            summary={k: v[0] for k, v in self.summary.items()},
            masked=self.masked[0],
            valid=self.valid[0],
            **{k: None if v is None else v[0] for k, v in optional.items()},
        )


def save_feature_maps(path: str, maps: TissueFeatureMaps, *, dt: float, dx: float | None) -> str:
    """Write the maps of one video to ``.npz`` atomically.

    The file holds one ``(H, W)`` array per map computed, ``masked``, ``dt`` in s, ``dx`` in mm when known,
    a ``units_<name>`` string per array and, with depth maps, the depth profiles ``(Z, H, W)`` on
    ``depth_mm`` ``(Z,)``. Every entry and its unit: ``docs/reference/outputs.md``, section
    ``anra features --out``.

    Returns:
        The path written, ``.npz`` appended when missing.

    Raises:
        OSError: the file cannot be written.
    """
    target = str(path) if str(path).endswith(".npz") else f"{path}.npz"
    arrays = {name: m.detach().cpu().numpy() for name, m in maps.maps.items()}
    arrays["masked"] = maps.masked.cpu().numpy()
    units = {name: maps.units[name] for name in maps.maps}
    spacing = {"dt": np.array(dt)} | ({} if dx is None else {"dx": np.array(dx)})
    profiles = None if maps.depth is None else maps.depth.profiles
    if profiles is not None:
        names = {"peak": ("peak_temperature_depth", "C"), "peak_std": ("peak_temperature_depth_std", "K")}
        names |= {"omega": ("omega_depth", "1"), "cem43": ("cem43_depth_minutes", "min")}
        arrays |= {name: getattr(profiles, key)[0].detach().cpu().numpy() for key, (name, _) in names.items()}
        arrays["depth_mm"] = profiles.depths.cpu().numpy()
        units |= dict(names.values()) | {"depth_mm": "mm"}
    strings = {f"units_{name}": np.array(unit) for name, unit in units.items()}
    with atomic_output(target) as temp, open(temp, "wb") as handle:
        np.savez_compressed(handle, **spacing, **arrays, **strings)
    return target


_RULE_TEXT = {
    "linear": "the frames joined by straight lines over the recorded span (T - 1) dt, integrated exactly",
    "hold": "each frame held for dt (the Sapareto-Dewey sum), T dt",
}


def dose_record(
    doses: tuple[str, ArrheniusConstants, Sequence[float]], frames: int, dt: float, sigma: float
) -> dict:
    """How the doses were computed: the JSON's ``dose``.

    Args:
        doses: the rule, the Arrhenius constants and the thresholds in C.
        frames: number of frames recorded.
        dt: frame period in s.
        sigma: the denoised history's Gaussian sigma in px.

    Returns:
        The rule, the span in s, the smoothing in px and every constant used.
    """
    rule, c, thresholds = doses
    return {
        "rule": rule,
        "integration": _RULE_TEXT[rule],
        "span_s": (frames - 1) * dt if rule == "linear" else frames * dt,
        "smoothing_px": sigma,
        "thresholds_C": list(thresholds),
        "cem43": {
            "formula": "integral R^(43 - T) dt / 60 min",
            "R_at_or_above_43C": CEM43_R[0],
            "R_below_43C": CEM43_R[1],
        },
        "arrhenius": {
            "formula": "integral A exp(-Ea / (R_gas T_K)) dt",
            "A_per_s": c.frequency,
            "Ea_J_per_mol": c.activation_energy,
            "R_gas_J_per_mol_K": GAS_CONSTANT,
        },
    }
