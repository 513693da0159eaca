"""Stepwise selection of effects (forward, then backward elimination) with Wald tests.

An effect enters when its p-value beats ``alpha / (effects left)`` (Bonferroni) plus its look-elsewhere
penalty (:attr:`~anra_torch.effects.EffectSpec.look_elsewhere`, for a fitted shape). Among the
significant candidates, the one that lowers the residual above its expected noise part most enters, a
fitted shape's drop discounted by the share of its statistic that its penalty stands for (Wald statistics
of non-nested models measure significance, not fit).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from torch import Tensor

from anra_torch.balance import BalanceSystem, Fit
from anra_torch.effects import EFFECTS, Context, Shape, simulated_span
from anra_torch.selection.statistics import search_discount, wald_score

__all__ = ["MIN_SHARE", "Selection", "checked_hints", "tried"]

MIN_SHARE = 0.01
"""The smallest share of ``dT/dt`` (:meth:`Selection.share`) an effect must make to be named: below it a
significant effect is listed as negligible (an operator's discretisation, a camera's residue, or a real but
small effect) and stays in the fit as a nuisance term (:meth:`Selection.nuisance_record`)."""


def checked_hints(
    hints: Mapping[str, Sequence[Mapping[str, float]]] | None,
) -> dict[str, tuple[dict[str, float], ...]]:
    """``hints`` (:func:`~anra_torch.selection.diagnose_terms`) checked: known effects, each candidate of a
    localised effect with a finite centre and a positive radius (mm); of an effect without a position
    (e.g. a depth term's plate, read by its own shape fit) finite values.

    Raises:
        ValueError: an unknown effect or a candidate without them.
    """
    out: dict[str, tuple[dict[str, float], ...]] = {}
    for name, candidates in (hints or {}).items():
        if name not in EFFECTS:
            raise ValueError(f"hints: unknown effect {name!r}; expected one of: {', '.join(EFFECTS)}")
        out[name] = tuple({k: float(v) for k, v in c.items()} for c in candidates)
        for c in out[name]:
            if not EFFECTS[name].positions:
                if not all(math.isfinite(v) for v in c.values()):
                    raise ValueError(f"hints[{name!r}] need finite values, got {c}")
            elif not (math.isfinite(c.get("x", math.nan)) and math.isfinite(c.get("y", math.nan))
                      and c.get("radius", 0.0) > 0):  # fmt: skip
                raise ValueError(f"hints[{name!r}] need a finite x, y and a positive radius in mm, got {c}")
    return out


def tried(names: Sequence[str], hints: Mapping[str, tuple[dict[str, float], ...]]) -> list[str]:
    """``names`` less the effects the balance's ``hints`` (:func:`checked_hints`) do not let the search try
    (:attr:`~anra_torch.effects.EffectSpec.tried`, e.g. a second delamination without two candidate
    regions): an effect never tried is not counted among those tested (each one's Bonferroni share)."""
    return [name for name in names if EFFECTS[name].tried(hints)]


class Selection:
    """Stepwise selection state: the effects in the model and the fitted extra terms."""

    def __init__(
        self,
        system: BalanceSystem,
        alpha: float,
        names: Sequence[str],
        background: float,
        shared: dict[tuple, Shape] | None = None,
    ) -> None:
        self.system, self.alpha, self.names, self.background = system, alpha, list(names), background
        # Shapes fitted by :meth:`take`, shared by the selections of one balance (fit_effects' models): a
        # shape fitted to what the same effects before it leave is the same fit in every model.
        self.shared = {} if shared is None else shared
        self.selected: list[str] = []
        frames = system.frames.detach()
        self.span = (float(frames.min()), float(frames.max()))  # the temperatures the video reaches
        self.fitted: dict[str, Shape] = {}  # each localised effect's last fitted shape
        self.scores: dict[str, float] = {}
        self.thresholds: dict[str, float] = {}
        self.negligible: dict[str, dict] = {}  # below their physical size, or unphysical in a given model
        self._fits: dict[tuple[str, ...], tuple[tuple[Tensor, ...], Fit]] = {}  # by columns: their terms, fit

    @property
    def shapes(self) -> dict[str, dict[str, float]]:
        """Fitted shape parameters by effect (kept on the balance, where dependent shape fits read them)."""
        return self.system.shapes

    def columns(self, effects: Sequence[str]) -> list[str]:
        return ["L"] + [r for e in effects for r in EFFECTS[e].regressors]

    def fit(self, effects: Sequence[str]) -> Fit:
        """The balance's fit of ``effects``' columns, computed once while their terms stay the same (the
        stepwise search asks for the same model's fit several times)."""
        columns = tuple(self.columns(effects))
        terms = tuple(self.system.terms[c] for c in columns)
        kept = self._fits.get(columns)
        if kept is not None and all(a is b for a, b in zip(kept[0], terms, strict=True)):
            return kept[1]
        current = self.system.terms  # fits of replaced terms go (they would hold the old terms' graphs)
        self._fits = {
            k: v for k, v in self._fits.items() if all(t is current[c] for t, c in zip(v[0], k, strict=True))
        }
        fit = self.system.fit(columns)
        self._fits[columns] = (terms, fit)
        return fit

    def context(self) -> Context:
        return Context(mean=self.system.mean, background=self.background, shape=self.shapes)

    def discount(self, name: str) -> float:
        """Share of ``name``'s last statistic that is not owed to the search over its shape."""
        spec = EFFECTS[name]
        return search_discount(spec.look_elsewhere, len(spec.regressors), self.scores[name])

    def reach(self, fitted: Mapping[str, dict[str, float]]) -> tuple[float, float]:
        """The temperatures a forecast of the ``fitted`` effects (their parameters by name) runs over: the
        video's, widened by the bounds each effect sets at any duration (a plate cooling towards its
        ``T_ref``) and by the simulation's margin (:func:`~anra_torch.effects.simulated_span`). Held-out flash
        plate 21 of experiments.flash_defect_map named a nonlinear diffusivity 0.03 mm^2/s at the frames'
        coolest and -0.5 over this range, and the forecast then ran no effect at all."""
        low, high = self.span
        for name, params in fitted.items():
            low, high = EFFECTS[name].bounds(params, low, high, 0.0)
        return simulated_span(low, high)

    def parameters(self, fit: Fit, names: Sequence[str]) -> dict[str, dict[str, float]]:
        """The parameters of ``names`` in ``fit``, by name."""
        coefficients, context = fit.coefficients(), self.context()
        return {name: EFFECTS[name].from_coefficients(coefficients, context) for name in names}

    def physical(self, name: str, params: dict[str, float], reach: tuple[float, float]) -> bool:
        """Whether fitted ``params`` are valid and simulable over the temperatures ``reach`` (:meth:`reach`;
        a nonlinear diffusivity that turns negative there cannot enter: the forecast could not run it)."""
        spec = EFFECTS[name]
        try:
            if spec.check is not None:
                spec.check(params)
            spec.rates(params, reach)
        except ValueError:
            return False
        return spec.valid(params) and self.in_view(name, params) and self.in_hint(name, params)

    def share(self, name: str, fit: Fit) -> float:
        """The effect's share of ``dT/dt`` in ``fit``: the RMS of its term (its coefficients times its
        regressors) over the RMS of ``U``, both over every balanced point and without their expected noise
        parts (1: as large as the whole rate of change). An effect held at a candidate region
        (:attr:`~anra_torch.effects.EffectSpec.footprint`) is measured where it acts: its mean square over
        the share of the points it covers, ``U``'s taken as the frame's (held-out flash plate 23 of
        experiments.flash_defect_map: a delamination at the map's defect, 0.95 % of the frame's rate of
        change, was listed as negligible)."""
        spec = EFFECTS[name]
        regressors = list(spec.regressors)
        beta = fit.beta[[fit.columns.index(r) for r in regressors]].detach()
        energy = float(beta @ self.system.moments.block(regressors, regressors) @ beta)
        total = float(self.system.moments.block(["U"], ["U"])[0, 0])
        if spec.footprint is not None and name in self.shapes:
            energy /= spec.footprint(self.shapes[name], self.system)
        return math.sqrt(max(energy, 0.0) / total) if total > 0 else math.inf

    def material(self, name: str, params: dict[str, float], fit: Fit) -> bool:
        """Whether the effect reaches its stated physical size (:attr:`EffectSpec.min_size`) over the
        video's temperatures; one that does not is kept in :attr:`negligible` (rule ``"size"``, with its
        share and size) and leaves the model. The share of ``dT/dt`` decides only whether a selected effect
        is named (:meth:`nuisance_record`): it stays in the fit either way."""
        spec = EFFECTS[name]
        if spec.size is None:
            self.negligible.pop(name, None)
            return True
        size = float(spec.size(params, self.span))
        if size >= spec.min_size:
            self.negligible.pop(name, None)
            return True
        self.negligible[name] = {**self.entry(name, params, fit), "rule": "size"}
        return False

    def nuisance_record(self, name: str, params: dict[str, float], fit: Fit) -> dict | None:
        """None when the selected effect is named (its :meth:`share` of ``dT/dt`` is at least
        :data:`MIN_SHARE`); else its ``negligible`` entry, rule ``"share"``: a nuisance term, too small to
        name, whose term stays in the fit so that the named effects' parameters are not biased by its
        absence (an intact flash plate's true loss, 0.94 % of ``dT/dt``: fitted without it the plate's
        ``a_y`` read 1.83 for a true 1.1, with it 1.09)."""
        record = self.entry(name, params, fit)
        return None if record["share"] >= MIN_SHARE else {**record, "rule": "share"}

    def entry(self, name: str, params: dict[str, float], fit: Fit) -> dict:
        """``{"name", "params", "share", "min_share"}`` and, for an effect that states a physical size,
        ``"size"`` and ``"min_size"``."""
        spec = EFFECTS[name]
        record = {
            "name": name,
            "params": dict(params),
            "share": self.share(name, fit),
            "min_share": MIN_SHARE,
        }
        if spec.size is not None:
            record.update(size=float(spec.size(params, self.span)), min_size=spec.min_size)
        return record

    def named(self, fit: Fit, given: Sequence[str] | None = None) -> tuple[list[dict], list[dict]]:
        """The selected effects named in ``fit``, ``{"name", "params", "score", "share"}`` by score (or in
        ``given``'s order), and the ``negligible`` entries of the nuisance terms: those under
        :data:`MIN_SHARE` (:meth:`nuisance_record`), or, with ``given``, those not in it."""
        coefficients, context = fit.coefficients(), self.context()
        found: list[dict] = []
        nuisance: list[dict] = []
        for name in self.selected:
            params = EFFECTS[name].from_coefficients(coefficients, context)
            small = self.nuisance_record(name, params, fit)
            if (given is None and small is not None) or (given is not None and name not in given):
                nuisance.append(small or {**self.entry(name, params, fit), "rule": "share"})
                continue
            score = wald_score(fit, EFFECTS[name].regressors)
            found.append({"name": name, "params": params, "score": score, "share": self.share(name, fit)})
        order = list(given or [])
        found.sort(key=lambda e: -e["score"] if given is None else order.index(e["name"]))
        return found, nuisance

    def in_view(self, name: str, params: dict[str, float]) -> bool:
        """Whether every position of a localised effect (:attr:`EffectSpec.positions`, mm) lies in the
        frame or within a quarter of its size around it: a shape fitted far outside the field of view is a
        term the model misses (e.g. a cooling into depth), not a source."""
        _, height, width = self.system.shape
        dx = self.system.dx
        for x_key, y_key in EFFECTS[name].positions:
            x, y = params[x_key] / (width * dx), params[y_key] / (height * dx)
            if not (-0.25 <= x <= 1.25 and -0.25 <= y <= 1.25):
                return False
        return True

    def drop_unphysical_given(self) -> None:
        """:meth:`drop_unphysical` (physical, not size) of a given model, each dropped effect kept in
        :attr:`negligible` (rule ``"unphysical"``) with the parameters it had in the model's fit."""
        fit = self.fit(self.selected)
        coefficients, context = fit.coefficients(), self.context()
        before = {name: EFFECTS[name].from_coefficients(coefficients, context) for name in self.selected}
        for name in self.drop_unphysical(material=False):
            self.negligible[name] = {"name": name, "params": before[name], "rule": "unphysical"}

    def in_hint(self, name: str, params: dict[str, float]) -> bool:
        """Whether a localised effect given candidate shapes (the balance's ``hints``, from
        :func:`~anra_torch.selection.diagnose_terms`: a flash defect map's defects for a delamination, where
        its shape fit starts) lies in one of them: its first position within the candidate's radius and its
        own radius (where it has one) at most twice the candidate's; true without hints. An empty set of
        candidates rules the effect out (:meth:`allowed`)."""
        hints = self.system.hints.get(name)
        if hints is None or not EFFECTS[name].positions:
            return True
        x_key, y_key = EFFECTS[name].positions[0]
        x, y, radius = params[x_key], params[y_key], params.get("radius", 0.0)
        return any(
            math.hypot(x - h["x"], y - h["y"]) <= h["radius"] and radius <= 2 * h["radius"] for h in hints
        )

    def threshold(self, name: str, tested: int) -> float:
        return -math.log10(self.alpha / tested) + EFFECTS[name].look_elsewhere

    def allowed(self, name: str, effects: Sequence[str]) -> bool:
        group = EFFECTS[name]
        return (
            name not in effects
            and all(needed in effects for needed in group.requires)
            and self.system.hints.get(name) != ()  # candidate shapes were looked for and none was found
            and group.tried(self.system.hints)
            and not (group.replaces_diffusion and any(EFFECTS[e].replaces_diffusion for e in effects))
        )

    def prepare(self, name: str, current: Fit, *, refine: bool = False) -> None:
        """Fit a localised effect's shape to what the current model leaves unexplained."""
        group = EFFECTS[name]
        if group.shape is None:
            return
        start = self.fitted[name].theta if refine and name in self.fitted else None
        fitted = group.shape(self.system, current, start)
        self._use(name, fitted)

    def _use(self, name: str, fitted: Shape) -> None:
        """Put a fitted shape's term into the balance and keep its parameters."""
        self.system.add(EFFECTS[name].regressors[0], fitted.term, fitted.noise)
        self.shapes[name] = fitted.params
        self.fitted[name] = fitted

    def take(self, names: Sequence[str]) -> None:
        """Put ``names`` into the model as given, in order, without a test: each localised shape fitted to
        what the effects before it leave (once per balance: :attr:`shared`), then (beside others) refitted
        to the model without itself."""
        for name in names:
            before = tuple(id(self.fitted[e]) for e in self.selected if e in self.fitted)
            key = (name, tuple(self.selected), before)
            if key in self.shared:
                self._use(name, self.shared[key])
            else:
                self.prepare(name, self.fit(self.selected))
                if name in self.fitted:
                    self.shared[key] = self.fitted[name]
            self.selected.append(name)
        for name in names:
            if name in self.shapes and len(names) > 1:
                self.refit(name)

    def unphysical(self, *, material: bool = False) -> set[str]:
        """The selected effects whose parameters in the current fit are not physical (or, with
        ``material``, below their physical size: :meth:`material` then updates :attr:`negligible`)."""
        fit = self.fit(self.selected)
        fitted = self.parameters(fit, self.selected)
        reach, bad = self.reach(fitted), set()
        for name, params in fitted.items():
            if not self.physical(name, params, reach) or (material and not self.material(name, params, fit)):
                bad.add(name)
        return bad

    def refit(self, name: str) -> None:
        """Refit a selected effect's shape to the final model without it, unless that makes another
        selected effect unphysical: then the shape of the forward search is kept. (An intact flash plate's
        depth shape refitted without itself turned its loss rate and then its a_y negative, and both were
        dropped.)"""
        before, bad = self.fitted.get(name), self.unphysical()
        others = [e for e in self.selected if e != name]
        self.prepare(name, self.system.fit(self.columns(others)), refine=True)
        if before is not None and self.unphysical() - bad:
            self._use(name, before)

    def forward(self) -> None:
        while True:
            candidates = [n for n in self.names if self.allowed(n, self.selected)]
            if not candidates:
                return
            current = self.fit(self.selected)
            current_excess = current.rss - self.system.expected_rss(current)
            eligible = {}
            for name in candidates:
                self.prepare(name, current, refine=name in self.fitted)
                fit = self.fit([*self.selected, name])
                self.scores[name] = wald_score(fit, EFFECTS[name].regressors)
                self.thresholds[name] = self.threshold(name, len(candidates))
                fitted = self.parameters(fit, [*self.selected, name])
                params = fitted[name]
                significant = self.scores[name] > self.thresholds[name] and self.physical(
                    name, params, self.reach(fitted)
                )
                if not significant:
                    self.negligible.pop(name, None)
                elif self.material(name, params, fit):
                    explained = current_excess - (fit.rss - self.system.expected_rss(fit))
                    eligible[name] = explained * search_discount(
                        EFFECTS[name].look_elsewhere, len(EFFECTS[name].regressors), self.scores[name]
                    )
            if not eligible:
                return
            # Among the significant effects the one that explains most enters: Wald statistics of
            # different (non-nested) models measure significance, not which model fits better. "Most"
            # is the drop of the residual above its expected noise part (the errors-in-variables fit does
            # not minimise the raw residual, and each model's noise part differs), less the share a
            # fitted shape owes to its search (_search_discount).
            self.selected.append(max(eligible, key=eligible.__getitem__))

    def drop_unphysical(self, *, material: bool = True) -> list[str]:
        """Remove, one at a time, effects whose parameters in the final fit are not physical, or (with
        ``material``) below their physical size (the fit moves when other effects leave or shapes are
        refitted): the one with the lowest score first, the later in the model among equal scores, with the
        effects that require it. Returns the removed effects in order."""
        removed: list[str] = []
        while bad := self.unphysical(material=material):
            worst = min(bad, key=lambda name: (self.scores.get(name, 0.0), -self.selected.index(name)))
            gone = [e for e in self.selected if e == worst or worst in EFFECTS[e].requires]
            self.selected[:] = [e for e in self.selected if e not in gone]
            removed.extend(gone)
        return removed

    def backward(self) -> Fit:
        """Drop effects that are no longer significant given the others; return the final fit."""
        while True:
            final = self.fit(self.selected)
            if not self.selected:
                return final
            tested = len(self.names)
            excess = {}
            for name in self.selected:
                self.scores[name] = wald_score(final, EFFECTS[name].regressors)
                self.thresholds[name] = self.threshold(name, tested)
                excess[name] = self.scores[name] - self.thresholds[name]
            worst = min(excess, key=excess.__getitem__)
            if excess[worst] > 0:
                return final
            self.selected.remove(worst)
