"""What the reports share (:mod:`anra_torch.report.figures`): numbers with their errors, the extent of a map
in mm, colour maps that show masked pixels, figures rendered on their own canvas and saved."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib
import numpy as np
import pytest

from anra_torch.report.figures import DPI, colormap, format_pm, import_matplotlib, mm_extent, save_figure

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize(
    ("value", "error", "unit", "expected"),
    [
        (0.2000312, 6.13e-5, "mm^2/s", "0.200031 ± 0.000061 mm^2/s"),
        (0.18, 0.082, "", "0.180 ± 0.082"),
        (12.345, 1.5, "s", "12.3 ± 1.5 s"),
        (0.2, math.nan, "", "0.2"),
        (0.2, 0.0, "mm", "0.2 mm"),
        (math.nan, 0.1, "mm^2/s", "n/a mm^2/s"),
    ],
)
def test_format_pm(value: float, error: float, unit: str, expected: str) -> None:
    assert format_pm(value, error, unit) == expected


def test_an_image_extent_in_mm_puts_row_zero_at_the_top() -> None:
    assert mm_extent(30, 40, 0.25) == (0.0, 10.0, 7.5, 0.0)


def test_masked_pixels_are_drawn_light_grey() -> None:
    cmap = colormap("inferno")
    assert cmap(np.nan) == pytest.approx((0.85, 0.85, 0.85, 1.0))
    assert cmap(0.0) == matplotlib.colormaps["inferno"](0.0)


def test_a_figure_is_saved_as_png_at_the_report_resolution_without_pyplot(tmp_path: Path) -> None:
    backend = matplotlib.get_backend()
    figure_cls, canvas_cls = import_matplotlib()
    fig = figure_cls(figsize=(2.0, 1.0))
    fig.add_subplot().imshow(np.eye(3), extent=mm_extent(3, 3, 0.5))
    save_figure(fig, canvas_cls, tmp_path / "f.png")
    data = (tmp_path / "f.png").read_bytes()
    assert data[:8] == PNG_MAGIC
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert (width, height) == (2 * DPI, 1 * DPI)
    assert matplotlib.get_backend() == backend
