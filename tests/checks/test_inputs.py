"""Input checks (:mod:`anra_torch.checks.inputs`): numbers, spacings, choices and value ranges, each with
its one-line error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from anra_torch.checks import in_range_values


# --------------------------------------------------------------------------------- the pieces alone
def test_in_range_values_masks_and_counts_like_numpy() -> None:
    rng = np.random.default_rng(0)
    values = 30 + rng.standard_normal((5, 6, 7))
    values[0, 0, :3] = [np.nan, np.inf, -np.inf]
    values[1, 2, 3], values[4, 5, 6] = 2e6, -1e300
    masked, found = in_range_values(torch.from_numpy(values))
    bad = ~np.isfinite(values) | (np.abs(np.nan_to_num(values, posinf=0, neginf=0)) > 1e6)
    np.testing.assert_array_equal(np.isnan(masked.numpy()), bad)
    np.testing.assert_array_equal(masked.numpy()[~bad], values[~bad])
    assert found == {"non_finite": 3, "beyond_limit": 2, "samples": 210, "limit": 1e6, "largest": 1e300}
    # integer counts: kept as they are unless one is beyond the limit
    counts = torch.tensor([[[20000, 65535]]], dtype=torch.int32)
    assert in_range_values(counts)[0] is counts
    big = in_range_values(torch.tensor([[[20000, 2**31 - 1]]], dtype=torch.int32))[0]
    assert big.dtype == torch.float64 and math.isnan(big[0, 0, 1]) and big[0, 0, 0] == 20000
    with pytest.raises(ValueError, match=r"got none: 0 non-finite and 0 beyond the limit of 0 samples"):
        in_range_values(torch.zeros(0, 4, 4))
