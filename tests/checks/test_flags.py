"""Result flags (:mod:`anra_torch.checks.flags`): implausible diffusivities, a model that fails."""

from __future__ import annotations

import math

from anra_torch.checks.flags import PLAUSIBLE_DIFFUSIVITY, diffusivity_warnings, model_failure


def test_diffusivity_warnings_name_the_unit_mix_up() -> None:
    low, high = PLAUSIBLE_DIFFUSIVITY
    assert diffusivity_warnings(0.15, dt=0.04, dx=0.1) == []
    assert (
        diffusivity_warnings(low, dt=0.04, dx=0.1) == [] and diffusivity_warnings(high, dt=0.04, dx=0.1) == []
    )
    # dt in ms: a reads 1000 times too small
    (warning,) = diffusivity_warnings(1.5e-4, dt=40.0, dx=0.1)
    assert "likely cause: dt = 40 given in ms instead of s (dt = 0.04 s would give 0.15 mm^2/s)" in warning
    assert warning.endswith("hardly change by lateral conduction (a flat baseline, a drift, a loss)")
    # dx in um: a reads 1e6 times too large
    (warning,) = diffusivity_warnings(1.5e5, dt=0.04, dx=100.0)
    assert "likely cause: dx = 100 given in um instead of mm (dx = 0.1 mm would give 0.15 mm^2/s)" in warning
    assert "lateral conduction" not in warning  # too large is never the data's stillness
    # nothing explains 1e30: the generic advice
    (warning,) = diffusivity_warnings(1e30, dt=0.04, dx=0.1)
    assert warning.endswith("check that dt is in s, dx in mm and the frames are temperatures")
    # negative: significant with a z-score, any with none; no warning for a non-finite value
    assert diffusivity_warnings(-0.15, dt=0.04, dx=0.1, z=-2.0) == []
    assert (
        "significantly negative (-5.0 standard errors"
        in diffusivity_warnings(-0.15, dt=0.04, dx=0.1, z=-5.0)[0]
    )
    assert diffusivity_warnings(-0.15, dt=0.04, dx=0.1)[0].startswith("the diffusivity is negative")
    assert (
        "(noise-free: a zero standard error)" in diffusivity_warnings(-0.15, dt=0.04, dx=0.1, z=-math.inf)[0]
    )
    assert diffusivity_warnings(math.nan, dt=0.04, dx=0.1) == []


def test_model_failure_states_the_ratio_to_the_floor() -> None:
    assert model_failure(0.003, 0.001) is None  # exactly 3 floors: still explained
    assert "RMSE 0.0031 is 3.1 times the noise floor 0.001" in model_failure(0.0031, 0.001)
    assert "is infinitely above the noise floor 0" in model_failure(0.1, 0.0)
    assert "not finite" in model_failure(math.nan, 0.001)
