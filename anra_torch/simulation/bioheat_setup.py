"""What the independent 3-D bioheat simulator (:func:`anra_torch.simulation.simulate_bioheat`) simulates:
the tissue, its sources (a Gaussian beam or tip, a contact probe), the depth cells, the camera's view, and
what it returns. Units: mm, s, C, mm^2/s.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["BioheatResult", "BioheatScene", "Contact", "DepthGrid", "SurfaceFlux", "Tissue"]


@dataclass(frozen=True)
class Tissue:
    """Homogeneous tissue.

    Attributes:
        diffusivity: ``a`` in mm^2/s.
        perfusion: ``b`` in 1/s.
        body_temperature: C; the tissue starts there and perfusion pulls towards it.
        air: ``h / k`` of the free surface in 1/mm (heat lost to air at the body temperature).
    """

    diffusivity: float = 0.14
    perfusion: float = 0.0
    body_temperature: float = 37.0
    air: float = 0.02


@dataclass(frozen=True)
class SurfaceFlux:
    """A Gaussian beam or tip moving from ``start`` to ``end`` (x, y in mm) while on, ``[t_on, t_off)``.

    Attributes:
        power: peak flux over ``rho c`` in K mm/s.
        width: Gaussian sigma in mm (``inf``: uniform over the surface).
        absorption: None for surface absorption; else ``mu`` in 1/mm (volumetric, near-infrared).
    """

    start: tuple[float, float]
    end: tuple[float, float]
    width: float
    power: float
    t_on: float
    t_off: float
    absorption: float | None = None


@dataclass(frozen=True)
class Contact:
    """A probe at ``temperature`` C on a disc (``radius`` mm, ``inf``: everywhere) during ``[t_on, t_off)``.

    Attributes:
        conductance: ``h / k`` of the contact in 1/mm (large: the surface follows the probe).
    """

    centre: tuple[float, float]
    radius: float
    temperature: float
    t_on: float
    t_off: float
    conductance: float = 50.0


@dataclass(frozen=True)
class DepthGrid:
    """Depth cells: ``first`` mm at the surface, growing by ``growth`` up to ``step`` mm, uniform down to
    ``uniform_to`` mm, then growing by ``deep_growth`` to ``bottom`` mm (held at the body temperature)."""

    first: float = 0.02
    growth: float = 1.3
    step: float = 0.08
    uniform_to: float = 3.5
    deep_growth: float = 1.25
    bottom: float = 15.0

    def faces(self) -> np.ndarray:
        """Face depths (mm) from 0 to the bottom, ``(Z + 1,)``."""
        z, size, faces = 0.0, self.first, [0.0]
        while z < self.bottom:
            grow = self.growth if z < self.uniform_to else self.deep_growth
            z += size
            faces.append(z)
            size = min(size * grow, self.step) if z < self.uniform_to else size * grow
        return np.array(faces)


@dataclass(frozen=True)
class BioheatScene:
    """What :func:`simulate_bioheat` simulates and how the camera looks at it.

    Attributes:
        tissue: :class:`Tissue`.
        sources: :class:`SurfaceFlux` and :class:`Contact` sources.
        duration: recorded time in s (frames at ``0, 1 / rate, ...``).
        shape: camera frame ``(H, W)`` px; x along W, y along H, from the frame's top-left corner.
        dx: camera pixel size in mm.
        rate: camera frame rate in Hz.
        margin: tissue beyond the camera's view on every side, mm.
    """

    tissue: Tissue
    sources: tuple[SurfaceFlux | Contact, ...]
    duration: float
    shape: tuple[int, int] = (48, 48)
    dx: float = 0.15
    rate: float = 10.0
    margin: float = 1.5
    label: str = ""


@dataclass(frozen=True)
class BioheatResult:
    """Output of :func:`simulate_bioheat`.

    Attributes:
        frames: noiseless camera frames in C, ``(T, H, W)``.
        dt: frame period (s); dx: pixel size (mm).
        damage_depth: deepest point with ``Omega >= 1`` under each pixel (mm; 0 without damage), ``(H, W)``.
        depths: cell-centre depths (mm), ``(Z,)``.
        log_omega: ``ln Omega`` per cell, pixel-averaged, ``(Z, H, W)`` (``-inf`` where nothing accrued).
        peak: peak temperature per cell (C), pixel-averaged, ``(Z, H, W)``.
        scene: the :class:`BioheatScene`.
    """

    frames: np.ndarray
    dt: float
    dx: float
    damage_depth: np.ndarray
    depths: np.ndarray
    log_omega: np.ndarray
    peak: np.ndarray
    scene: BioheatScene
    info: dict = field(default_factory=dict)
