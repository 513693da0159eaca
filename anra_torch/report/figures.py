"""What the reports share: number formatting, the matplotlib import, axes in mm, colour maps and saving.

matplotlib is imported only when a report is written and drawn through its object API on the Agg canvas, so
writing a report never changes the caller's pyplot backend or state.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from anra_torch.checks import atomic_output

__all__ = ["colormap", "format_pm", "import_matplotlib", "mm_extent", "save_figure"]

DPI = 110
"""Resolution of every report figure (dots per inch)."""


def format_pm(value: float, error: float | None, unit: str = "") -> str:
    """``value ± error unit`` with the error to two significant digits (``nan`` shown as ``n/a``).

    Example:
        >>> format_pm(0.2000312, 6.13e-5, "mm^2/s")
        '0.200031 ± 0.000061 mm^2/s'
    """
    suffix = f" {unit}" if unit else ""
    if not math.isfinite(value):
        return f"n/a{suffix}"
    if error is None or not math.isfinite(error) or error <= 0:
        return f"{value:.6g}{suffix}"
    decimals = max(0, 1 - math.floor(math.log10(error)))
    if decimals > 12:
        return f"{value:.6g} ± {error:.2g}{suffix}"
    return f"{value:.{decimals}f} ± {error:.{decimals}f}{suffix}"


def import_matplotlib() -> tuple[Any, Any]:
    """matplotlib's ``Figure`` and Agg canvas classes.

    Raises:
        ImportError: matplotlib missing, naming the extra to install.
    """
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as err:
        raise ImportError(
            "writing a report needs matplotlib, which is not installed: pip install anra_torch[plot]"
        ) from err
    return Figure, FigureCanvasAgg


def mm_extent(h: int, w: int, dx: float) -> tuple[float, float, float, float]:
    """imshow extent in mm of an ``(h, w)`` px image, x along columns, y along rows (row 0 at the top)."""
    return (0.0, w * dx, h * dx, 0.0)


def save_figure(fig: Any, canvas_cls: Any, path: Path) -> None:
    """Render ``fig`` on a new ``canvas_cls`` canvas and write it to ``path`` at :data:`DPI` (atomically)."""
    canvas_cls(fig)
    with atomic_output(path) as temp:
        fig.savefig(temp, dpi=DPI)


def colormap(name: str) -> Any:
    """The matplotlib colour map ``name`` with NaN drawn light grey."""
    from matplotlib import colormaps

    return colormaps[name].with_extremes(bad="0.85")  # NaN: pixels the filters cannot reach
