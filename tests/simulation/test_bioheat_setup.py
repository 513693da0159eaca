"""The independent bioheat simulator's setup: the depth cells grow, stay uniform, then grow to the bottom."""

from __future__ import annotations

import numpy as np

from anra_torch.simulation.bioheat_setup import DepthGrid


def test_depth_cells_grow_to_the_step_stay_uniform_then_grow_to_the_bottom() -> None:
    grid = DepthGrid(first=0.02, growth=1.3, step=0.08, uniform_to=1.0, deep_growth=1.25, bottom=5.0)
    faces = grid.faces()
    sizes = np.diff(faces)
    assert faces[0] == 0.0 and faces[-1] >= 5.0 and faces[-2] < 5.0
    assert sizes[0] == 0.02 and bool((sizes <= 0.08 + 1e-12)[faces[:-1] < 1.0].all())
    np.testing.assert_allclose(sizes[1:4] / sizes[:3], 1.3)  # growing from the surface
    shallow = sizes[(faces[:-1] > 0.5) & (faces[1:] < 1.0)]
    np.testing.assert_allclose(shallow, 0.08)  # uniform down to uniform_to
    deep = sizes[faces[:-1] > 1.2]
    np.testing.assert_allclose(deep[1:] / deep[:-1], 1.25)  # then growing to the bottom
