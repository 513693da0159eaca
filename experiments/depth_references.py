"""The plain ANRA estimate and the depth-aware fit against the true ``a`` on 3-D conduction that shares no
code with the package (the references are in ``tests/depth_references.py``, where the tests assert on them):
this script prints the results page's table.

    python -m experiments.depth_references      # about 10 s
"""

from __future__ import annotations

import numpy as np

from anra_torch.estimation.estimator import ANRAEstimator
from anra_torch.selection.depth_aware import depth_aware_diffusivity
from tests.depth_references import A, beam_heated_slab, half_space_gaussian


def main() -> None:
    gaussian, s2 = half_space_gaussian()
    slab = beam_heated_slab()
    cases = [
        ("surface of a Gaussian spreading in a half-space (separable, exact)", gaussian, 1.0, 0.25),
        ("explicit slab, beam on 120 s, cooling from the switch-off", slab, 10.0, 0.5),
        ("the same slab from 60 s after the switch-off", slab[6:], 10.0, 0.5),
    ]
    print("| 3-D reference | plain `a` (ANRA) | depth-aware `a` |")
    print("|---|---|---|")
    for name, frames, dt, dx in cases:
        plain = float(ANRAEstimator()(frames, dt, dx).diffusivity)
        fit = depth_aware_diffusivity(frames, dt, dx)
        consistent = "consistent" if fit.consistent else "not consistent"
        depth = 100 * (fit.diffusivity / A - 1)
        print(f"| {name} | {100 * (plain / A - 1):+.0f} % | {depth:+.1f} %, {consistent} |")
    rates = depth_aware_diffusivity(gaussian, 1.0, 0.25).rates
    error = np.abs(np.asarray(rates) / (A / s2[2:-2]) - 1)
    median, most = 100 * np.median(error), 100 * error.max()
    print(f"\nhalf-space rates against a / s^2(t): median {median:.1f} %, max {most:.1f} %")


if __name__ == "__main__":
    main()
