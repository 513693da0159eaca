"""Stepwise selection (:mod:`anra_torch.selection.stepwise`) on exact solutions with white noise: the one
effect a video holds enters, the rest do not; backward elimination drops what the others explain; the
rules of which effects may enter together.

``T = 25 + (c(x, y, t) + 3) e^(-b t)`` with ``c = 0.01 (x^3 + y^3 + 6 a t (x + y))`` solves
``dT/dt = a Lap T - b (T - 25)``: a linear loss and nothing else.
"""

from __future__ import annotations

import math

import pytest
import torch

from anra_torch.balance import BalanceSystem
from anra_torch.effects import simulated_span
from anra_torch.selection.stepwise import Selection

F64 = torch.float64
DT, DX, A = 0.1, 0.5, 0.3  # s, mm, mm^2/s
NAMES = ["linear_loss", "advection", "anisotropy", "nonlinear_diffusion"]


def loss_video(b: float, seed: int = 0, size: int = 24) -> torch.Tensor:
    t = (torch.arange(24, dtype=F64) * DT)[:, None, None]
    y = (torch.arange(size, dtype=F64) * DX)[None, :, None] - 5.0
    x = (torch.arange(size, dtype=F64) * DX)[None, None, :] - 6.0
    heat = 0.01 * (x**3 + y**3 + 6 * A * t * (x + y))
    noise = 0.01 * torch.randn(24, size, size, generator=torch.Generator().manual_seed(seed), dtype=F64)
    return 25.0 + (heat + 3.0) * torch.exp(-b * t) + noise


def selection(b: float) -> Selection:
    system = BalanceSystem(loss_video(b), DT, DX, sigma=1.0, noise_sd=0.01)
    return Selection(system, 0.01, NAMES, background=25.0)


def test_the_loss_enters_alone_and_stays() -> None:
    chosen = selection(0.5)
    chosen.forward()
    assert chosen.selected == ["linear_loss"]
    assert chosen.scores["linear_loss"] > 1e3  # measured 2e6
    assert all(chosen.scores[n] < chosen.thresholds[n] for n in NAMES[1:])  # measured <= 0.5
    fit = chosen.backward()
    assert chosen.selected == ["linear_loss"]
    coefficients = fit.coefficients()
    assert coefficients["T"] == pytest.approx(-0.5, rel=0.01) and coefficients["L"] == pytest.approx(
        A, rel=0.05
    )


def test_pure_diffusion_selects_nothing_at_bonferroni_thresholds() -> None:
    chosen = selection(0.0)
    chosen.forward()
    assert chosen.selected == []
    assert chosen.thresholds == {n: pytest.approx(-math.log10(0.01 / 4)) for n in NAMES}  # 4 candidates
    assert chosen.backward().columns == ("L",)


def test_backward_elimination_drops_what_the_others_explain() -> None:
    chosen = selection(0.5)
    chosen.selected = ["advection", "linear_loss"]
    fit = chosen.backward()
    assert chosen.selected == ["linear_loss"] and fit.columns == ("L", "T", "1")
    assert chosen.thresholds["advection"] == pytest.approx(-math.log10(0.01 / 4))


def test_which_effects_may_enter_together() -> None:
    chosen = selection(0.0)
    assert chosen.allowed("anisotropy", ["linear_loss"])
    assert not chosen.allowed("linear_loss", ["linear_loss"])
    assert not chosen.allowed("nonlinear_diffusion", ["anisotropy"])  # both replace a Lap T
    assert not chosen.allowed("delamination", ["linear_loss"])  # needs depth_conduction in the model
    assert chosen.allowed("delamination", ["depth_conduction"])
    assert chosen.columns(["linear_loss", "advection"]) == ["L", "T", "1", "T_x", "T_y"]
    # A localised effect's positions must lie in the 12 x 12 mm frame or within a quarter of it around.
    disc = {"x": 6.0, "y": 6.0, "radius": 2.0, "a_inside": 0.2, "a_outside": 0.3}
    assert chosen.in_view("heterogeneity", disc)
    assert chosen.in_view("heterogeneity", {**disc, "x": -2.9})
    assert not chosen.in_view("heterogeneity", {**disc, "x": -3.1})
    assert not chosen.physical("heterogeneity", {**disc, "y": 40.0}, chosen.span)


def test_an_effect_is_checked_over_the_temperatures_the_forecast_reaches() -> None:
    """A loss towards an ambient below the frames cools the forecast there (its bounds, at any duration):
    a nonlinear diffusivity positive over the frames but not down to the ambient cannot be simulated, so it
    is not physical (held-out flash plate 21 of experiments.flash_defect_map named one, and its forecast
    then ran no effect at all)."""
    t = (torch.arange(24, dtype=F64) * DT)[:, None, None]
    warmer = loss_video(0.5) + 3.0 * torch.exp(-0.5 * t)  # T = 25 + (c + 6) e^(-b t): the same loss
    chosen = Selection(BalanceSystem(warmer, DT, DX, sigma=1.0, noise_sd=0.01), 0.01, NAMES, background=25.0)
    low, high = chosen.span
    assert low > 25.5  # the frames stay above the ambient, 25 C
    fitted = chosen.parameters(chosen.fit(["linear_loss"]), ["linear_loss"])
    ambient = fitted["linear_loss"]["T_ref"]
    assert ambient == pytest.approx(25.0, abs=0.1)
    reach = chosen.reach(fitted)
    assert reach == pytest.approx(simulated_span(ambient, high))  # down to the loss's T_ref
    assert chosen.reach({}) == pytest.approx(simulated_span(low, high))
    nonlinear = {"a0": A, "beta": 1 / (high - 24.3), "T_ref": high}  # a(T) = 0 at 24.3 C
    assert chosen.physical("nonlinear_diffusion", nonlinear, simulated_span(low, high))
    assert not chosen.physical("nonlinear_diffusion", nonlinear, reach)


def test_a_shape_fitted_after_the_same_effects_is_fitted_once_per_balance(monkeypatch) -> None:
    """The models of one balance (``fit_effects``) share :attr:`Selection.shared`: a shape fitted to what
    the same effects before it leave is fitted once, and is the fit a selection of its own makes; after
    other effects it is fitted anew."""
    system = BalanceSystem(loss_video(0.5, size=16), DT, DX, sigma=1.0, noise_sd=0.01)
    alone = Selection(system, 0.01, ["depth_conduction"], background=25.0)
    alone.take(alone.names)
    fitted: list[str] = []
    prepare = Selection.prepare

    def counted(self: Selection, name: str, current, *, refine: bool = False) -> None:
        fitted.append(f"{name}{'+' if refine else ''}")
        prepare(self, name, current, refine=refine)

    monkeypatch.setattr(Selection, "prepare", counted)
    shared: dict = {}
    models = [["depth_conduction", "linear_loss"], ["depth_conduction"], ["linear_loss", "depth_conduction"]]
    selections = [Selection(system, 0.01, m, background=25.0, shared=shared) for m in models]
    for chosen in selections:
        chosen.take(chosen.names)
    assert fitted == [
        "depth_conduction",
        "linear_loss",
        "depth_conduction+",
        "linear_loss",
        "depth_conduction",
        "depth_conduction+",
    ]
    assert torch.equal(selections[1].fitted["depth_conduction"].theta, alone.fitted["depth_conduction"].theta)
    assert not torch.equal(
        selections[2].fitted["depth_conduction"].theta, alone.fitted["depth_conduction"].theta
    )


def test_a_model_is_fitted_once_while_its_terms_stay_the_same(monkeypatch) -> None:
    """:meth:`Selection.fit` computes a model's fit once and gives it again while its columns' terms are the
    same tensors; a shape fitted anew (a new term) is fitted anew, and the result is the balance's fit."""
    system = BalanceSystem(loss_video(0.5, size=16), DT, DX, sigma=1.0, noise_sd=0.01)
    selection = Selection(system, 0.01, ["depth_conduction", "linear_loss"], background=25.0)
    selection.take(["depth_conduction"])
    fits: list[tuple[str, ...]] = []
    fit = BalanceSystem.fit

    def counted(self: BalanceSystem, columns):
        fits.append(tuple(columns))
        return fit(self, columns)

    monkeypatch.setattr(BalanceSystem, "fit", counted)
    first = selection.fit(["depth_conduction", "linear_loss"])
    assert selection.fit(["depth_conduction", "linear_loss"]) is first
    assert fits == [("L", "Z", "T", "1")]
    torch.testing.assert_close(first.beta, fit(system, first.columns).beta, rtol=0, atol=0)
    selection.prepare("depth_conduction", selection.fit(["linear_loss"]), refine=True)  # a new Z term
    again = selection.fit(["depth_conduction", "linear_loss"])
    assert again is not first and fits == [("L", "Z", "T", "1"), ("L", "T", "1"), ("L", "Z", "T", "1")]


def test_hints_of_an_effect_without_a_position_need_finite_values_not_a_centre() -> None:
    from anra_torch.selection.stepwise import checked_hints

    plate = {"T_ref": 20.0, "plate_time": 9.3, "t_heat": -0.1}
    assert checked_hints({"depth_conduction": [plate]}) == {"depth_conduction": (plate,)}
    with pytest.raises(ValueError, match=r"hints\['depth_conduction'\] need finite values"):
        checked_hints({"depth_conduction": [{**plate, "T_ref": math.nan}]})
    with pytest.raises(ValueError, match=r"hints\['delamination'\] need a finite x, y and a positive radius"):
        checked_hints({"delamination": [plate]})
