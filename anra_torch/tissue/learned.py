"""A tissue model learned end to end from video, through the simulator of :mod:`anra_torch.simulation.tissue`.

The model (Pennes-like bioheat equation per unit heat capacity, on the pixel grid)::

    dT/dt = div(a(x, y) grad T) - b(x, y) (T - T_body) + q(t, x, y)

with ``a`` the diffusivity field in mm^2/s, ``b`` the perfusion / loss-rate field in 1/s and ``q`` an
optional :class:`anra_torch.simulation.MovingSource` in K/s; :func:`anra_torch.simulation.simulate_tissue`
integrates it with fixed-step RK4, and gradients flow to the fields.

:class:`LearnedTissueModel` holds ``log a`` and ``log b`` on a coarse grid (bilinear up-sampling to the
frame: a smooth, positive field with few parameters), initialised from ANRA's direct estimate
(:class:`anra_torch.estimation.ANRAEstimator` windowed field for ``a``, the loss-rate map of
:class:`anra_torch.tissue.TissueFeatures` for ``b``), and :meth:`LearnedTissueModel.fit` trains them by
back-propagating the frame misfit through the ODE solver.

:func:`omega_with_constants` is the layer's Arrhenius dose with constants that vary per pixel and carry
gradients: a model that learns a tissue's damage threshold trains its constants through it.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from tqdm.auto import tqdm

from anra_torch.checks import as_spacing, as_video
from anra_torch.estimation import ANRAEstimator
from anra_torch.selection import diagnose_terms
from anra_torch.simulation import simulate_tissue
from anra_torch.tissue.dose import GAS_CONSTANT, KELVIN_AT_ZERO_CELSIUS, SKIN, arrhenius_omega, to_celsius

__all__ = ["LearnedTissueModel", "omega_with_constants", "relative_error"]

_F64 = torch.float64
_SPAN = math.log(10.0)  # learned fields stay within a factor 10 of their start (keeps RK4 steps bounded)


def _pool(field: Tensor, weight: Tensor, grid: tuple[int, int]) -> Tensor:
    """Weighted average of ``field`` ``(H, W)`` on a coarse ``grid`` (cells without weight: NaN)."""
    num = F.adaptive_avg_pool2d((field * weight)[None, None], grid)[0, 0]
    den = F.adaptive_avg_pool2d(weight[None, None], grid)[0, 0]
    return torch.where(den > 0, num / torch.where(den > 0, den, 1.0), torch.nan)


class LearnedTissueModel(nn.Module):
    """Diffusivity and perfusion fields learned end to end through the RK4 simulator.

    ``log a`` and ``log b`` live on a coarse ``grid`` and are up-sampled bilinearly to the frame; both
    stay positive. Start them with :meth:`from_video` (ANRA's direct estimate) and train with :meth:`fit`.

    Args:
        shape: frame size ``(H, W)`` in px.
        dx: pixel size in mm.
        diffusivity: initial ``a`` in mm^2/s, a number or a coarse field ``grid``.
        perfusion: initial ``b`` in 1/s, a number or a coarse field ``grid``.
        grid: coarse grid ``(h, w)`` of the learned fields.
        body_temperature: initial ``T_body`` (units of T), learned as well.

    Shape:
        :attr:`diffusivity`, :attr:`perfusion`: ``(H, W)``; ``forward(initial, n_frames, dt)``:
        ``(H, W)`` -> ``(T, H, W)``.
    """

    def __init__(
        self,
        shape: tuple[int, int],
        dx: float,
        *,
        diffusivity: float | Tensor = 0.1,
        perfusion: float | Tensor = 0.01,
        grid: tuple[int, int] = (6, 6),
        body_temperature: float = 37.0,
    ) -> None:
        super().__init__()
        self.shape, self.dx, self.grid = tuple(shape), float(dx), tuple(grid)
        if not math.isfinite(body_temperature):
            raise ValueError(f"body_temperature must be finite, got {body_temperature!r}")
        self.body_temperature = nn.Parameter(torch.tensor(float(body_temperature), dtype=_F64, device="cpu"))

        def start(value: float | Tensor, name: str, unit: str) -> Tensor:
            v = (
                value.to(_F64)
                if isinstance(value, Tensor)
                else torch.as_tensor(value, dtype=_F64, device="cpu")
            )
            v = v.expand(self.grid) if v.ndim == 0 else v
            if tuple(v.shape) != self.grid:
                raise ValueError(f"{name} must be a number or have shape {self.grid}, got {tuple(v.shape)}")
            if not bool(torch.isfinite(v).all()) or bool((v <= 0).any()):
                raise ValueError(f"{name} must be positive and finite in {unit}, got min {float(v.min()):g}")
            return v.log().clone()

        # Learned: theta in log a = log a_0 + span tanh(theta): a stays within a factor e^span of its start.
        self.register_buffer("log_diffusivity_start", start(diffusivity, "diffusivity", "mm^2/s"))
        self.register_buffer("log_perfusion_start", start(perfusion, "perfusion", "1/s"))
        self.diffusivity_theta = nn.Parameter(torch.zeros(self.grid, dtype=_F64, device="cpu"))
        self.perfusion_theta = nn.Parameter(torch.zeros(self.grid, dtype=_F64, device="cpu"))

    @classmethod
    def from_video(
        cls,
        frames: Tensor,
        dt: float,
        dx: float,
        *,
        grid: tuple[int, int] = (6, 6),
        body_temperature: float | None = None,
        window: int = 9,
    ) -> LearnedTissueModel:
        """A model initialised from ANRA's direct estimate of one video ``(T, H, W)``.

        ``a`` starts at the estimator's windowed field averaged over each coarse cell (weighted by its
        confidence; the global estimate where a cell has none), kept within a factor 4 of the global
        estimate. ``b`` and ``T_body`` start at the
        ``linear_loss`` found by :func:`anra_torch.selection.diagnose_terms` (restricted to that effect);
        without one, ``b = 1e-3 1/s`` and ``T_body`` the median of the first frame. A given
        ``body_temperature`` overrides the diagnosed one.

        Raises:
            ValueError: bad shape, or no measurable thermal activity.
        """
        video, batched = as_video(frames, name="frames")
        if batched:
            raise ValueError(f"frames must have shape (T, H, W), got {tuple(video.shape)}")
        video = video[0].to(_F64)
        est = ANRAEstimator(window=window, strict=False)(video, dt, dx)
        if not bool(est.valid):
            raise ValueError(f"frames: {est.messages}; cannot initialise from the direct estimate")
        a_global = float(est.diffusivity)
        a = _pool(torch.nan_to_num(est.field, nan=0.0), est.confidence, grid)
        # A window with little signal can read far off: keep the start within a factor 4 of the global a.
        a = torch.nan_to_num(a, nan=a_global).clamp(a_global / 4, 4 * a_global)
        b, body = 1e-3, float(video[0].median())
        diagnosis = diagnose_terms(video, dt, dx, effects=["linear_loss"])
        if diagnosis.effects:
            params = diagnosis.effects[0]["params"]
            b, body = max(params["b"], 1e-3), params["T_ref"]
        body = body if body_temperature is None else float(body_temperature)
        return cls(tuple(video.shape[1:]), dx, diffusivity=a, perfusion=b, grid=grid, body_temperature=body)

    def _upsample(self, coarse: Tensor) -> Tensor:
        return F.interpolate(coarse[None, None], size=self.shape, mode="bilinear", align_corners=False)[0, 0]

    @property
    def diffusivity(self) -> Tensor:
        """``a`` on the frame, mm^2/s, ``(H, W)``."""
        log_a = self.log_diffusivity_start + _SPAN * torch.tanh(self.diffusivity_theta)
        return self._upsample(log_a).exp()

    @property
    def perfusion(self) -> Tensor:
        """``b`` on the frame, 1/s, ``(H, W)``."""
        log_b = self.log_perfusion_start + _SPAN * torch.tanh(self.perfusion_theta)
        return self._upsample(log_b).exp()

    def forward(self, initial: Tensor, n_frames: int, dt: float) -> Tensor:
        """Simulated video from ``initial`` ``(H, W)``: ``(n_frames, H, W)``."""
        return simulate_tissue(
            initial.to(_F64),
            self.diffusivity,
            self.perfusion,
            dx=self.dx,
            dt=dt,
            n_frames=n_frames,
            body_temperature=self.body_temperature,
        )

    def loss(self, frames: Tensor, dt: float) -> Tensor:
        """Mean squared misfit (units of T squared) of the video simulated from ``frames[0]``."""
        video = frames.to(_F64)
        return (self(video[0], video.shape[0], dt) - video).pow(2)[1:].mean()

    def fit(self, frames: Tensor, dt: float, *, steps: int = 30, progress: bool = False) -> list[float]:
        """Train both fields with L-BFGS (strong Wolfe line search) on :meth:`loss`.

        Every evaluation back-propagates the misfit through the RK4 solver.

        Args:
            frames: the measured video (units of T).
            dt: frame period in s.
            steps: L-BFGS iterations.
            progress: show a progress bar.

        Returns:
            The loss at every evaluation, starting with the initial one (units of T squared).

        Shape:
            ``frames`` ``(T, H, W)`` with ``(H, W)`` the model's shape.
        """
        video = frames.detach().to(_F64)
        if video.ndim != 3 or tuple(video.shape[1:]) != self.shape:
            raise ValueError(
                f"frames must have shape (T, {self.shape[0]}, {self.shape[1]}), got {tuple(video.shape)}"
            )
        if not bool(torch.isfinite(video).all()):
            raise ValueError("frames must be finite to train the tissue model; crop or fill them first")
        optimiser = torch.optim.LBFGS(
            self.parameters(), lr=1.0, max_iter=steps, history_size=20, line_search_fn="strong_wolfe"
        )
        history: list[float] = []
        bar = tqdm(total=steps, desc="tissue model", disable=not progress)

        def closure() -> Tensor:
            optimiser.zero_grad()
            loss = self.loss(video, dt)
            loss.backward()
            history.append(loss.item())
            bar.update(1)
            return loss

        optimiser.step(closure)
        bar.close()
        with torch.no_grad():
            history.append(self.loss(video, dt).item())
        return history

    def extra_repr(self) -> str:
        return f"shape={self.shape}, grid={self.grid}, dx={self.dx:g}"


def relative_error(estimate: Tensor, truth: Tensor, mask: Tensor | None = None) -> float:
    """Median of ``|estimate / truth - 1|`` over ``mask`` (all pixels by default)."""
    ratio = (estimate / truth - 1).abs()
    return float(ratio[mask].median() if mask is not None else ratio.median())


def _pixel_constants(given: dict[str, float | Tensor], kelvin: Tensor) -> list[Tensor]:
    """The constants as float64 tensors on ``kelvin``'s device, checked to broadcast with its pixels and be
    finite (``Ea > 0``), with the time axis added: ``(..., H, W)`` -> ``(..., 1, H, W)``."""
    pixels = (*kelvin.shape[:-3], *kelvin.shape[-2:])
    out = []
    for name, value in given.items():
        c = torch.as_tensor(value, dtype=_F64, device=kelvin.device)
        try:
            fits = len(torch.broadcast_shapes(pixels, c.shape)) <= 3
        except RuntimeError:
            fits = False
        if not fits:
            raise ValueError(
                f"{name} must broadcast with the pixels {pixels} (3 dimensions at most), got {tuple(c.shape)}"
            )
        if not bool(torch.isfinite(c.detach()).all()):
            raise ValueError(f"{name} must be finite, got {c.detach().flatten()[:4].tolist()}")
        if name == "activation_energy" and bool((c.detach() <= 0).any()):
            raise ValueError(f"activation_energy must be > 0 J/mol, got min {float(c.detach().min()):g}")
        out.append(c.unsqueeze(-3) if c.ndim >= 2 else c)
    return out


def omega_with_constants(
    temperatures: Tensor,
    dt: float | Tensor,
    *,
    log_frequency: float | Tensor,
    activation_energy: float | Tensor,
    units: str = "C",
    rule: str = "hold",
) -> Tensor:
    """Arrhenius Omega ``integral exp(ln A - Ea / (R_gas T_K)) dt`` with per-pixel, differentiable constants.

    ``ln A`` and ``Ea`` are tensors broadcast with the pixels, and the gradient flows to them and to the
    temperatures. ``rule="hold"`` is exact; ``"linear"`` differs from
    :func:`anra_torch.tissue.arrhenius_omega` by a relative ``(dT / T)^2`` per segment. Constants with a
    leading axis of their own, e.g. ``(K, 1, 1)``, evaluate one history ``(T, H, W)`` under several pairs at
    once. How: ``docs/guides/tissue-damage.md``, section "Arrhenius constants that learn".

    Args:
        temperatures: video in ``units``, ``"C"`` or ``"K"``; dt: frame period in s, a number or ``(B,)``.
        log_frequency: ``ln A`` with ``A`` in 1/s, a number or a tensor that broadcasts with the output.
        activation_energy: ``Ea`` in J/mol, > 0, likewise.
        rule: ``"hold"``, the default, or ``"linear"``; see :data:`anra_torch.tissue.RULES`.

    Returns:
        Omega, dimensionless, float64.

    Raises:
        ValueError: bad shapes, ``dt``, ``rule`` or ``units``; constants that are not finite, ``Ea <= 0``,
            or so far from the skin constants that an equivalent temperature is not positive.

    Shape:
        ``(T, H, W)`` or ``(B, T, H, W)``, constants broadcast with ``(H, W)`` or ``(B, H, W)`` -> their
        broadcast shape (at most 3 dimensions).
    """
    if getattr(temperatures, "ndim", None) not in (3, 4):
        shape = tuple(getattr(temperatures, "shape", ()))
        raise ValueError(f"temperatures must have shape (T, H, W) or (B, T, H, W), got {shape}")
    kelvin = to_celsius(temperatures, units) + 273.15
    given = {"log_frequency": log_frequency, "activation_energy": activation_energy}
    log_a, energy = _pixel_constants(given, kelvin)
    excess = GAS_CONSTANT * (log_a - math.log(SKIN.frequency))
    # The denominator falls as T rises: its smallest value is at each pixel's hottest frame.
    finite = torch.isfinite(kelvin)
    hottest = torch.where(finite, kelvin, 0.0).amax(-3, keepdim=True).detach()
    if bool((energy.detach() / hottest - excess.detach() <= 0).any()):
        raise ValueError(
            "log_frequency and activation_energy are too far from the skin constants for an equivalent "
            "temperature at these temperatures (ln A - Ea / (R_gas T_K) must stay below ln A_skin)"
        )
    if rule == "hold":  # one exp per frame and pair (the equivalent temperature's three passes saved)
        period = as_spacing(dt, name="dt", unit="s", batch=math.prod(kelvin.shape[:-3]), like=kelvin)
        safe = torch.where(finite, kelvin, KELVIN_AT_ZERO_CELSIUS + 43.0).to(_F64)  # no NaN in a branch
        rate = torch.where(finite, torch.exp(log_a - energy / (GAS_CONSTANT * safe)), 0.0)
        return rate.sum(-3) * (period.view(-1, 1, 1) if kelvin.ndim == 4 else period.view(()))
    return arrhenius_omega(SKIN.activation_energy / (energy / kelvin - excess), dt, units="K", rule=rule)
