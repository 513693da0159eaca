"""The depth maps of :class:`anra_torch.tissue.TissueFeatures` and ``anra features --depth``.

:func:`depth_features` fits ``a`` and ``b`` on the recording's cooling
(:func:`anra_torch.tissue.depth_fit.fit_depth_parameters`) and maps the damage in depth with their
standard errors and the noise's (:func:`anra_torch.tissue.depth_damage.damage_in_depth`). A video whose fit is
not possible (no cooling recorded) or that looks volumetrically heated gets NaN maps and the reason: the
model's number would not describe it. Units: mm, s, C.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from anra_torch.tissue.depth_damage import (
    CEM43_THRESHOLD,
    DepthMaps,
    DepthSettings,
    StandardErrors,
    damage_in_depth,
)
from anra_torch.tissue.depth_fit import DepthParameters, fit_depth_parameters
from anra_torch.tissue.dose import SKIN, ArrheniusConstants

__all__ = ["DEPTH_MAPS", "MAP_SETTINGS", "PRIOR", "DepthFeatures", "depth_features"]

_F64 = torch.float64

_SOURCES = {
    "damage_depth_mm": "damage_depth",
    "damage_depth_std_mm": "damage_depth_std",
    "cem43_depth_mm": "cem43_depth",
    "cem43_depth_std_mm": "cem43_depth_std",
}
DEPTH_MAPS: tuple[str, ...] = tuple(_SOURCES)
MAP_MARGIN = None
"""How far the maps' frames are continued beyond every edge: as far as the heat reaches over the record,
like the fit's (:func:`anra_torch.tissue.depth_cooling.margin_mm`: 2.4 mm or 1.2 diffusion lengths, at most
6.4 mm), by a Gaussian tail (the frame is a window onto the tissue; a fixed 0.8 mm held the heat of
minute-long exposures in: 0.17 mm too deep with the true ``a`` and ``b``)."""
MAP_GROWTH = 1.06
"""Ratio of consecutive depth spacings of the maps' nodes: 6 % per node moves the damage depth (``ln Omega``
interpolated between nodes) by under 2e-4 mm from the 3 % grid on the validation scenes, at half the work."""
MAP_COARSE = 2
"""The maps' perturbed solves (``a + se``, ``b + se``: the parameters' part of the standard errors) on the
frames' ``2 x 2`` px means (:func:`anra_torch.tissue.damage_in_depth`'s ``coarse``): the base at full
resolution, the copies' changes vary smoothly across pixels."""
MAP_SETTINGS = DepthSettings(
    growth=MAP_GROWTH, margin=MAP_MARGIN, coarse=MAP_COARSE, curved=True, between=True
)
"""The maps' :class:`~anra_torch.tissue.DepthSettings` (skin's constants, the linear rule, 240 min)."""
PRIOR: dict[str, tuple[float, float]] = {"diffusivity": (0.14, 0.03), "loss_rate": (0.005, 0.005)}
"""Textbook skin values with wide standard errors (value, standard error) for a recording whose cooling
cannot be fitted (none recorded, or nothing above the noise): ``a`` 0.14 mm^2/s (0.08-0.20 within two
standard errors), ``b`` 0.005 1/s."""
"""The ``(H, W)`` depth maps (mm) :class:`anra_torch.tissue.TissueFeatures` adds with ``depth=True``."""


@dataclass(frozen=True)
class DepthFeatures:
    """The depth maps of a batch with the parameters they used (batched: leading ``B``).

    Attributes:
        maps: :data:`DEPTH_MAPS` name -> ``(B, H, W)`` (mm); NaN for a video flagged as volumetrically
            heated, with the reason in ``messages``.
        profiles: the :class:`DepthMaps` of the videos with maps (``(B, Z, H, W)`` profiles, NaN likewise),
            or None when no video has them.
        parameters: the :class:`anra_torch.tissue.depth_fit.DepthParameters` of every video (where they are
            not valid, the maps used :data:`PRIOR`).
        used: whether a video's maps were computed, ``(B,)``.
        messages: per video, why there are no maps, what is flagged or that the prior was used ("" otherwise).
        used_parameters: the ``diffusivity``, ``loss_rate``, their ``_std`` and ``noise_sd`` the maps used,
            each ``(B,)``: the fit's, or :data:`PRIOR` where it is not valid.
        thickness: the layer's thickness (mm) or None (half-space).
    """

    maps: dict[str, Tensor]
    profiles: DepthMaps | None
    parameters: DepthParameters
    used: Tensor
    messages: tuple[str, ...]
    used_parameters: dict[str, Tensor]
    thickness: float | None = None

    def record(self, index: int = 0) -> dict:
        """The assumptions and the parameters of video ``index`` as a JSON-ready record."""
        p = self.parameters
        value = lambda t: float(t[index]) if bool(torch.isfinite(t[index])) else None  # noqa: E731
        record = {
            "absorption": "at the surface: the frames are the tissue's surface temperature and no heat is "
            "deposited below it (near-infrared lasers, vaporisation and charring are outside the model)",
            "geometry": "half-space"
            if self.thickness is None
            else f"layer of {self.thickness:g} mm over tissue held at the body temperature",
            "model": "dT/dt = a (d_xx + d_yy + d_zz) T - b (T - T_body) under the frame, the frames as the "
            "surface temperature, continued beyond the frame's edges (a Gaussian tail through each edge's "
            "last pixels) as far as the heat reaches, in equilibrium with the first",
            "diffusivity_mm2_s": value(self.used_parameters["diffusivity"]),
            "diffusivity_std_mm2_s": value(self.used_parameters["diffusivity_std"]),
            "loss_rate_per_s": value(self.used_parameters["loss_rate"]),
            "loss_rate_std_per_s": value(self.used_parameters["loss_rate_std"]),
            "parameters_from": p.method if bool(p.valid[index]) else "textbook prior (no fit: see message)",
            "noise_sd_K": value(p.noise_sd),
            "cooling_start_frame": int(p.cooling_start[index]),
            "misfit": value(p.misfit),
            "volumetric": bool(p.volumetric[index]),
            "maps": bool(self.used[index]),
            "message": self.messages[index],
        }
        if self.profiles is not None:
            record |= {
                "body_temperature_C": value(self.profiles.body_temperature),
                "max_depth_mm": float(self.profiles.depths[-1]),
                "nodes": int(self.profiles.depths.numel()),
                "cem43_threshold_min": self.profiles.cem43_threshold,
            }
        return record


def depth_features(
    frames: Tensor,
    dt: float | Tensor,
    dx: float | Tensor,
    *,
    units: str = "C",
    constants: ArrheniusConstants = SKIN,
    rule: str = "linear",
    cem43_threshold: float = CEM43_THRESHOLD,
    thickness: float | None = None,
) -> DepthFeatures:
    """Fit ``a`` and ``b`` (:func:`anra_torch.tissue.depth_fit.fit_depth_parameters`) and map the damage in
    depth (:func:`damage_in_depth`) with their standard errors and the noise's, for every video not flagged
    as volumetric (with :data:`PRIOR` where the fit is not possible).

    Args:
        frames: surface temperatures in ``units`` (finite), ``(T, H, W)`` or ``(B, T, H, W)``.
        dt, dx: frame period (s) and pixel size (mm).
        units, constants, rule, cem43_threshold, thickness: as :func:`damage_in_depth`.

    Returns:
        :class:`DepthFeatures` (batched: a single video keeps ``B = 1``); maps ``(B, H, W)``.
    """
    video = frames if frames.ndim == 4 else frames.unsqueeze(0)
    parameters = fit_depth_parameters(video, dt, dx, units=units)
    used = ~parameters.volumetric  # never absorbed into a number
    chosen = {}
    for name, (value, error) in PRIOR.items():
        std = getattr(parameters, f"{name}_std")
        chosen[name] = torch.where(parameters.valid, getattr(parameters, name), value)
        chosen[f"{name}_std"] = torch.where(parameters.valid, std, error)
    chosen["noise_sd"] = parameters.noise_sd
    b, (h, w) = video.shape[0], video.shape[-2:]
    nan = torch.full((b, h, w), torch.nan, dtype=_F64, device=video.device)
    maps = {name: nan.clone() for name in DEPTH_MAPS}
    profiles = None
    if bool(used.any()):
        pick = torch.nonzero(used).flatten()
        spacing = [s if not isinstance(s, Tensor) or s.numel() == 1 else s[pick] for s in (dt, dx)]
        settings = replace(MAP_SETTINGS, constants=constants, rule=rule, cem43_threshold=cem43_threshold)
        errors = [chosen[name][pick] for name in ("diffusivity_std", "loss_rate_std", "noise_sd")]
        found = damage_in_depth(
            video[pick].to(torch.float32),  # within the error budget (1e-5 K): twice as fast
            *spacing,
            diffusivity=chosen["diffusivity"][pick],
            loss_rate=chosen["loss_rate"][pick],
            errors=StandardErrors(*errors),
            thickness=thickness,
            units=units,
            settings=settings,
        )
        for name, field_name in _SOURCES.items():
            maps[name][pick] = getattr(found, field_name).to(_F64)
        profiles = _scatter(found, pick, b)
    messages = tuple(
        f"{m}; the textbook prior used instead (a 0.14 +- 0.03 mm^2/s, b 0.005 +- 0.005 1/s)" if not ok else m
        for m, ok in zip(parameters.messages, parameters.valid.tolist(), strict=True)
    )
    return DepthFeatures(maps, profiles, parameters, used, messages, chosen, thickness)


def _scatter(found: DepthMaps, pick: Tensor, batch: int) -> DepthMaps:
    """``found`` (the videos ``pick``) in a batch of ``batch`` with NaN for the others."""
    changes = {}
    for key, value in found.__dict__.items():
        if isinstance(value, Tensor) and key != "depths":
            full = torch.full((batch, *value.shape[1:]), torch.nan, dtype=value.dtype, device=value.device)
            if value.dtype == torch.bool:
                full = torch.zeros((batch, *value.shape[1:]), dtype=torch.bool, device=value.device)
            full[pick] = value.detach()
            changes[key] = full
    return replace(found, **changes)
