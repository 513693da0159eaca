"""Tolerances for comparisons that are exact up to rounding, derived from the dtype's epsilon."""

from __future__ import annotations

import torch


def assert_rounding_close(
    actual: torch.Tensor,
    expected: torch.Tensor,
    *,
    scale: float | None = None,
    ops: int = 16,
    dtype: torch.dtype | None = None,
) -> None:
    """Assert equality up to rounding in ``expected``'s dtype, whatever the CPU's summation order.

    The tolerance is ``ops`` machine epsilons of the magnitudes involved: relative to each value, and
    absolute relative to ``scale`` (default the largest ``|expected|``), which covers values that come out
    near zero as sums of larger terms. ``dtype`` is the precision the values were computed in (default
    ``expected``'s).
    """
    eps = torch.finfo(expected.dtype if dtype is None else dtype).eps
    magnitude = float(expected.abs().max()) if scale is None else float(scale)
    torch.testing.assert_close(actual, expected, rtol=ops * eps, atol=ops * eps * max(magnitude, 1e-30))
