"""The learned tissue model (:mod:`anra_torch.tissue.learned`): training lowers the loss and recovers
planted fields; the Arrhenius dose with per-pixel constants equals the layer's dose and its gradient checks.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.layers import GaussianSmoothing
from anra_torch.simulation import simulate_tissue
from anra_torch.tissue.dose import ArrheniusConstants, arrhenius_omega
from anra_torch.tissue.learned import LearnedTissueModel, omega_with_constants, relative_error

F64 = torch.float64


# --------------------------------------------------------------------------------- learned model
def planted_scene(seed: int = 0) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, float, float]:
    """Textured tissue (37-47 C) with a diffusivity bump (0.1-0.25 mm^2/s) and a perfusion ramp
    (0.05-0.2 1/s), 32 x 32 px of 0.25 mm, 41 frames at 10 Hz, noise sd 0.05 K."""
    generator = torch.Generator().manual_seed(seed)
    h = w = 32
    dx, dt = 0.25, 0.1
    x = (torch.arange(w, dtype=F64) + 0.5) * dx
    r2 = (x[None, :] - 4.0) ** 2 + (x[:, None] - 4.0) ** 2
    a_true = 0.1 + 0.15 * torch.exp(-r2 / (2 * 2.0**2))
    b_true = 0.05 + 0.15 * x[None, :].expand(h, w) / 8.0
    texture = GaussianSmoothing(2.0, border="reflect")(torch.randn(1, h, w, generator=generator, dtype=F64))[
        0
    ]
    u0 = 37.0 + 10.0 * (texture - texture.min()) / (texture.max() - texture.min())
    clean = simulate_tissue(u0, a_true, b_true, dx=dx, dt=dt, n_frames=41)
    video = clean + 0.05 * torch.randn(clean.shape, generator=generator, dtype=F64)
    return video, a_true, b_true, dx, dt


@pytest.mark.slow
def test_short_training_lowers_the_loss() -> None:
    video, a_true, _, dx, dt = planted_scene()
    model = LearnedTissueModel.from_video(video, dt, dx)
    history = model.fit(video, dt, steps=4)
    assert history[-1] < 0.5 * history[0]
    assert all(math.isfinite(v) for v in history)


@pytest.mark.slow
def test_training_recovers_the_planted_fields() -> None:
    video, a_true, b_true, dx, dt = planted_scene()
    model = LearnedTissueModel.from_video(video, dt, dx)
    start_a = relative_error(model.diffusivity.detach(), a_true)
    history = model.fit(video, dt, steps=40)
    a_error = relative_error(model.diffusivity.detach(), a_true)
    b_error = relative_error(model.perfusion.detach(), b_true)
    # Measured (seed 0): median error of the diffusivity 36 % -> 2.4 %, perfusion 32 % -> 5.1 %,
    # T_body 36.07 -> 36.79 C (true 37); the loss reaches the noise variance 0.0025 K^2 (0.00263).
    assert history[-1] < 1.1 * 0.05**2
    assert a_error < 0.05 < 0.3 < start_a
    assert b_error < 0.10


# ------------------------------------------------------------------------ dose with learned constants
TISSUE_CONSTANTS = [(3.1e98, 6.28e5), (7.39e39, 2.577e5), (5.6e63, 4.3e5)]  # skin, liver, arterial wall


def burn_history(frames: int = 91, dt: float = 0.5) -> torch.Tensor:
    """Four pixels heated from 37 C to 54.5-72 C and cooled, ``(T, 2, 2)``."""
    t = torch.arange(frames, dtype=F64) * dt
    return 37.0 + 35.0 * torch.exp(-(((t - 12.0) / 8.0) ** 2))[:, None, None] * torch.linspace(
        0.5, 1.0, 4, dtype=F64
    ).view(1, 2, 2)


@pytest.mark.parametrize(("frequency", "energy"), TISSUE_CONSTANTS)
def test_omega_with_constants_is_the_layers_dose_with_those_constants(
    frequency: float, energy: float
) -> None:
    history = burn_history()
    constants = ArrheniusConstants(frequency, energy)
    given = {"log_frequency": math.log(frequency), "activation_energy": energy}
    hold = omega_with_constants(history, 0.5, **given)
    torch.testing.assert_close(hold, arrhenius_omega(history, 0.5, constants=constants), rtol=1e-12, atol=0)
    # "linear" joins the equivalent temperatures by lines: measured 7e-5 relative at most here.
    linear = omega_with_constants(history, 0.5, rule="linear", **given)
    reference = arrhenius_omega(history, 0.5, constants=constants, rule="linear")
    torch.testing.assert_close(linear, reference, rtol=1e-4, atol=0)


def test_omega_with_constants_per_pixel_and_per_video() -> None:
    history = burn_history()
    log_a = torch.tensor([math.log(a) for a, _ in TISSUE_CONSTANTS] + [math.log(3.1e98)], dtype=F64)
    energy = torch.tensor([e for _, e in TISSUE_CONSTANTS] + [6.28e5], dtype=F64)
    per_pixel = omega_with_constants(
        history, 0.5, log_frequency=log_a.view(2, 2), activation_energy=energy.view(2, 2)
    )
    for k, (frequency, e) in enumerate([*TISSUE_CONSTANTS, TISSUE_CONSTANTS[0]]):
        alone = arrhenius_omega(history, 0.5, constants=ArrheniusConstants(frequency, e))
        assert float(per_pixel.flatten()[k]) == pytest.approx(float(alone.flatten()[k]), rel=1e-12)
    # A batch: one pair of constants per video, (B, 1, 1).
    videos = torch.stack([history, history + 3.0])
    batched = omega_with_constants(
        videos, 0.5, log_frequency=log_a[:2].view(2, 1, 1), activation_energy=energy[:2].view(2, 1, 1)
    )
    second = arrhenius_omega(history + 3.0, 0.5, constants=ArrheniusConstants(*TISSUE_CONSTANTS[1]))
    torch.testing.assert_close(batched[1], second, rtol=1e-12, atol=0)
    # A frame that is not finite is left out as arrhenius_omega leaves it out (float32 in, float64 out).
    gappy = history.clone()
    gappy[10, 0, 1] = math.nan
    given = {"log_frequency": log_a.view(2, 2), "activation_energy": energy.view(2, 2)}
    with_gap = omega_with_constants(gappy.float(), torch.tensor([0.5]), **given)
    assert with_gap.dtype == F64 and bool(torch.isfinite(with_gap).all())
    second_pixel = arrhenius_omega(gappy.float(), 0.5, constants=ArrheniusConstants(*TISSUE_CONSTANTS[1]))
    assert float(with_gap[0, 1]) == pytest.approx(float(second_pixel[0, 1]), rel=1e-12)
    # One history under several pairs at once: constants with a leading axis of their own, (K, 1, 1).
    several = omega_with_constants(
        history, 0.5, log_frequency=log_a[:3].view(3, 1, 1), activation_energy=energy[:3].view(3, 1, 1)
    )
    assert several.shape == (3, 2, 2)
    for k, (frequency, e) in enumerate(TISSUE_CONSTANTS):
        alone = arrhenius_omega(history, 0.5, constants=ArrheniusConstants(frequency, e))
        torch.testing.assert_close(several[k], alone, rtol=1e-12, atol=0)


@pytest.mark.parametrize("rule", ["hold", "linear"])
def test_gradcheck_of_the_learned_constants(rule: str) -> None:
    """Float64 gradcheck of Omega in ``ln A``, ``Ea`` (in 100 kJ/mol, so that a finite difference is not
    lost in rounding) and the temperatures, on a 2 x 2 px history of 6 frames."""
    history = burn_history(frames=6, dt=4.0).clone().requires_grad_(True)
    log_a = torch.tensor([[92.0, 147.0], [226.0, 150.0]], dtype=F64, requires_grad=True)
    energy = torch.tensor([[2.6, 4.3], [6.28, 4.4]], dtype=F64, requires_grad=True)

    def omega(t: torch.Tensor, la: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
        return omega_with_constants(t, 4.0, log_frequency=la, activation_energy=1e5 * e, rule=rule)

    assert torch.autograd.gradcheck(omega, (history, log_a, energy), eps=1e-6, atol=1e-7, rtol=1e-5)


def test_omega_with_constants_refuses_bad_constants() -> None:
    history = burn_history(frames=8)
    with pytest.raises(ValueError, match="activation_energy must be > 0 J/mol"):
        omega_with_constants(history, 0.5, log_frequency=90.0, activation_energy=0.0)
    with pytest.raises(ValueError, match=r"log_frequency must broadcast with the pixels \(2, 2\)"):
        omega_with_constants(history, 0.5, log_frequency=torch.zeros(3, 3), activation_energy=2e5)
    with pytest.raises(ValueError, match="activation_energy must be finite"):
        omega_with_constants(history, 0.5, log_frequency=90.0, activation_energy=torch.tensor(math.nan))
    with pytest.raises(ValueError, match="too far from the skin constants"):
        omega_with_constants(history, 0.5, log_frequency=400.0, activation_energy=1e5)
    with pytest.raises(ValueError, match=r"shape \(T, H, W\) or \(B, T, H, W\), got \(8,\)"):
        omega_with_constants(history[:, 0, 0], 0.5, log_frequency=90.0, activation_energy=2e5)
