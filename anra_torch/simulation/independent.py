"""An independent solver of the continuous heat equation with its effects: none of the library's operators.

:func:`simulate_continuum` solves the continuous PDE :class:`Continuum` in a periodic domain padded around
the frame and images it as a camera does, as pixel averages. The PDE holds a constant or varying
diffusivity, advection, a loss, heat inputs and conduction into a plate below; each effect module says
what its parameters mean for it, :attr:`anra_torch.effects.EffectSpec.continuum`. ``"spectral"`` evolves
each Fourier mode exactly; ``"finite_volume"`` steps finite volumes on a finer grid by TR-BDF2. Why and
how: ``docs/architecture.md``, "The independent solver". Units: mm, s, mm^2/s; float64 NumPy.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from anra_torch.checks import check_choice, check_int, check_shape, number
from anra_torch.simulation.krylov import gmres
from anra_torch.simulation.plate import with_depth

__all__ = ["METHODS", "Continuum", "ContinuumGrid", "Forcing", "gaussian_cells", "simulate_continuum"]

_F64 = torch.float64
METHODS = ("auto", "spectral", "finite_volume")
"""``ContinuumGrid(method=...)``: ``"auto"`` takes the spectral solution when the model allows it."""

_GAMMA = 2.0 - math.sqrt(2.0)  # TR-BDF2: both stages then solve (I - (gamma / 2) h F)
_STAGE = 0.5 * _GAMMA
_GAUSS = (-math.sqrt(0.6), 0.0, math.sqrt(0.6))  # Gauss-Legendre nodes on [-1, 1] and their weights
_WEIGHTS = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)
_NEWTON_STEPS = 8
_TOLERANCE = 1e-10  # of the temperature span: stage equations are solved to this


# ------------------------------------------------------------------------------- continuous model
Forcing = Callable[[float, np.ndarray, np.ndarray], np.ndarray]
"""``(t in s, x edges (Nx + 1,), y edges (Ny + 1,) in mm) -> heat input averaged over each cell (Ny, Nx)``."""


@dataclass
class Continuum:
    """The continuous PDE ``dT/dt = div(A grad T) - dot(v, grad T) - b (T - T_ref) + q(t, x, y)``.

    ``A`` is the constant tensor ``[[a_x, a_xy], [a_xy, a_y]]``, replaced by ``a I`` when ``diffusivity``,
    a field ``a(x, y)``, or ``conductivity``, ``a(T) = a0 (1 + beta (T - T_ref))``, is given.

    Attributes:
        tensor: ``(a_x, a_y, a_xy)`` in mm^2/s.
        velocity: ``(vx, vy)`` in mm/s.
        loss: ``b`` in 1/s.
        ambient: ``T_ref`` of the loss.
        forcings: heat inputs, each a :data:`Forcing`, in data units per s.
        diffusivity: ``a(x, y)`` in mm^2/s at points in mm, on NumPy arrays; or None.
        conductivity: ``(a0, beta, T_ref)`` of a temperature-dependent diffusivity, or None.
        depth: ``(strength, t_heat, depth_time, T_ref)`` of conduction into a plate below the surface, or
            None. ``T - T_ref`` is then the rest of the linear model's solution times
            ``(theta(t - t_heat) / theta(-t_heat))^strength``, the plate's exact depth factor
            :func:`~anra_torch.simulation.plate.plate_factor`.

    Shape:
        ``diffusivity`` maps broadcastable ``x``, ``y`` to their broadcast shape.
    """

    tensor: tuple[float, float, float]
    velocity: tuple[float, float] = (0.0, 0.0)
    loss: float = 0.0
    ambient: float = 0.0
    forcings: list[Forcing] = field(default_factory=list)
    diffusivity: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    conductivity: tuple[float, float, float] | None = None
    depth: tuple[float, float, float, float] | None = None

    @property
    def spectral(self) -> bool:
        """Whether every coefficient is constant and nothing is added: each Fourier mode evolves alone."""
        return not self.forcings and self.diffusivity is None and self.conductivity is None


_erf = np.vectorize(math.erf, otypes=[np.float64])


def gaussian_cells(edges: np.ndarray, centre: float, width: float) -> np.ndarray:
    """``exp(-(x - centre)^2 / (2 width^2))`` averaged over each cell between ``edges``, exactly by erf.

    Shape:
        ``edges`` ``(N + 1,)`` in mm -> ``(N,)``.
    """
    s = math.sqrt(2.0) * width
    integral = _erf((edges[1:] - centre) / s) - _erf((edges[:-1] - centre) / s)
    return integral * (0.5 * math.sqrt(math.pi) * s) / np.diff(edges)


# -------------------------------------------------------------------------------------- domain
@dataclass(frozen=True)
class _Domain:
    """The periodic padded domain on a grid ``refine`` times finer than the camera's."""

    shape: tuple[int, int]  # frame (H, W) in px
    dx: float  # camera pixel in mm
    pad: int  # camera px on each side
    refine: int

    @property
    def cells(self) -> tuple[int, int]:
        return tuple((n + 2 * self.pad) * self.refine for n in self.shape)  # type: ignore[return-value]

    @property
    def h(self) -> float:
        return self.dx / self.refine

    def edges(self, axis: int) -> np.ndarray:
        """Cell edges in mm along the rows, y, for ``axis=0`` or the columns, x, for ``axis=1``; the frame
        starts at 0."""
        return (np.arange(self.cells[axis] + 1) - self.pad * self.refine) * self.h

    def centres(self, axis: int) -> np.ndarray:
        e = self.edges(axis)
        return 0.5 * (e[1:] + e[:-1])

    def average(self, initial: Callable[[Tensor, Tensor], Tensor]) -> np.ndarray:
        """Cell averages of ``initial`` by 3 x 3-point Gauss-Legendre quadrature, ``(Ny, Nx)``."""
        nodes, weights = np.array(_GAUSS) * (0.5 * self.h), np.array(_WEIGHTS)
        y = (self.centres(0)[:, None] + nodes[None, :]).reshape(-1)
        x = (self.centres(1)[:, None] + nodes[None, :]).reshape(-1)
        values = _evaluate(initial, x, y).reshape(self.cells[0], 3, self.cells[1], 3)
        return np.einsum("iajb,a,b->ij", values, weights, weights)

    def pixels(self, u: np.ndarray) -> np.ndarray:
        """The camera's frame: ``u`` averaged over each pixel of the frame, ``(H, W)``."""
        r, p = self.refine, self.pad * self.refine
        height, width = self.shape
        frame = u[p : p + height * r, p : p + width * r]
        return frame.reshape(height, r, width, r).mean((1, 3))


def _evaluate(initial: Callable[[Tensor, Tensor], Tensor], x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``initial`` on the grid of rows ``y`` by columns ``x``, ``(Ny, Nx)`` float64; ValueError where it is
    not finite."""
    values = initial(torch.from_numpy(x)[None, :], torch.from_numpy(y)[:, None])
    out = torch.as_tensor(values, dtype=_F64, device="cpu").expand(y.size, x.size).numpy()
    if not np.isfinite(out).all():
        raise ValueError("initial must give finite temperatures over the padded domain")
    return out


# ------------------------------------------------------------------------------------ spectral
def _spectral(model: Continuum, initial: np.ndarray, dx: float, pad: int, times: np.ndarray) -> np.ndarray:
    """Exact Fourier-mode evolution of ``initial``, pixel-centre samples of the padded domain, and the
    frame's pixel averages at ``times``, ``(T, H, W)``."""
    ny, nx = initial.shape
    base = model.ambient if model.loss > 0 else float(initial.mean())  # the loss relaxes to T_ref
    ky = 2.0 * math.pi * np.fft.fftfreq(ny, dx)[:, None]
    kx = 2.0 * math.pi * np.fft.rfftfreq(nx, dx)[None, :]
    a_x, a_y, a_xy = model.tensor
    vx, vy = model.velocity
    rate = -(a_x * kx**2 + a_y * ky**2 + 2.0 * a_xy * kx * ky) - model.loss - 1j * (vx * kx + vy * ky)
    pixel = np.sinc(kx * dx / (2.0 * math.pi)) * np.sinc(ky * dx / (2.0 * math.pi))  # the box average
    modes = np.fft.rfft2(initial - base) * pixel
    height, width = ny - 2 * pad, nx - 2 * pad
    frames = np.empty((times.size, height, width))
    for k, t in enumerate(times):
        frames[k] = np.fft.irfft2(modes * np.exp(rate * t), s=(ny, nx))[pad : pad + height, pad : pad + width]
    return frames + base


# ------------------------------------------------------------------------------- finite volumes
def _shift(u: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """``u[i + rows, j + cols]`` on the periodic grid."""
    return np.roll(u, (-rows, -cols), axis=(0, 1))


def _divergence(fx: np.ndarray, fy: np.ndarray, h: float) -> np.ndarray:
    """Net inflow per area from the fluxes ``fx`` through the east and ``fy`` through the south faces."""
    return (fx - _shift(fx, 0, -1) + fy - _shift(fy, -1, 0)) / h


def _constant_operator(
    u: np.ndarray, model: Continuum, tensor: tuple[float, float, float], h: float
) -> np.ndarray:
    """``div(A grad u - v u) - b u`` with constant ``A``, ``v``, ``b`` in flux form on central faces."""
    a_x, a_y, a_xy = tensor
    vx, vy = model.velocity
    east, south = _shift(u, 0, 1), _shift(u, 1, 0)
    fx = a_x * (east - u) / h - vx * 0.5 * (u + east)
    fy = a_y * (south - u) / h - vy * 0.5 * (u + south)
    if a_xy != 0.0:  # the tangential derivative on a face: the mean of its two cells' central ones
        d_y = (south - _shift(u, -1, 0)) / (2.0 * h)
        d_x = (east - _shift(u, 0, -1)) / (2.0 * h)
        fx = fx + a_xy * 0.5 * (d_y + _shift(d_y, 0, 1))
        fy = fy + a_xy * 0.5 * (d_x + _shift(d_x, 1, 0))
    return _divergence(fx, fy, h) - model.loss * u


class _Operators:
    """``F(t, u) = C u + K(u) + g(t)`` on the domain's cells: ``C`` the constant-coefficient part, diagonal
    in Fourier space; ``K(u) = div((a - a_ref) grad u)`` the varying diffusion; ``g`` the heat inputs."""

    def __init__(self, model: Continuum, domain: _Domain, span: tuple[float, float]) -> None:
        self.model, self.h = model, domain.h
        self.edges = (domain.edges(1), domain.edges(0))
        self.tolerance = _TOLERANCE * max(span[1] - span[0], 1e-300)
        self.face_x = self.face_y = None
        a_ref, tensor = 0.0, model.tensor
        if model.diffusivity is not None:  # a(x, y) at the east and south faces of each cell
            xc, yc = domain.centres(1)[None, :], domain.centres(0)[:, None]
            face_x = model.diffusivity(domain.edges(1)[None, 1:], yc)
            face_y = model.diffusivity(xc, domain.edges(0)[1:, None])
            a_ref = 0.5 * (min(face_x.min(), face_y.min()) + max(face_x.max(), face_y.max()))
            self.face_x, self.face_y = face_x - a_ref, face_y - a_ref
        elif model.conductivity is not None:  # the middle of a(T) over the temperatures seen
            a0, beta, t_ref = model.conductivity
            a_ref = a0 * (1.0 + beta * (0.5 * (span[0] + span[1]) - t_ref))
        if self.variable:
            tensor = (a_ref, a_ref, 0.0)
        self.a_ref = a_ref
        delta = np.zeros(domain.cells)
        delta[0, 0] = 1.0  # C is a circular convolution: its symbol is the transform of its impulse response
        self.symbol = np.fft.rfft2(_constant_operator(delta, model, tensor, self.h))

    @property
    def variable(self) -> bool:
        return self.model.diffusivity is not None or self.model.conductivity is not None

    def constant(self, u: np.ndarray) -> np.ndarray:
        return np.fft.irfft2(np.fft.rfft2(u) * self.symbol, s=u.shape)

    def inverse(self, r: np.ndarray, c: float) -> np.ndarray:
        """``(I - c C)^-1 r``, exact by FFT; the symbol's real part is <= 0."""
        return np.fft.irfft2(np.fft.rfft2(r) / (1.0 - c * self.symbol), s=r.shape)

    def forcing(self, t: float) -> np.ndarray | float:
        g: np.ndarray | float = self.model.loss * self.model.ambient
        for q in self.model.forcings:
            g = g + q(t, *self.edges)
        return g

    def _faces(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``a - a_ref`` at the east and south faces; for a conductivity, the two cells' mean ``a(T)``."""
        if self.model.conductivity is None:
            return self.face_x, self.face_y  # type: ignore[return-value]
        a0, beta, t_ref = self.model.conductivity
        level = a0 * (1.0 - beta * t_ref) - self.a_ref
        return level + 0.5 * a0 * beta * (u + _shift(u, 0, 1)), level + 0.5 * a0 * beta * (
            u + _shift(u, 1, 0)
        )

    def _flux(self, faces: tuple[np.ndarray, np.ndarray], v: np.ndarray) -> np.ndarray:
        """``div(faces grad v)``."""
        return (
            _divergence(faces[0] * (_shift(v, 0, 1) - v), faces[1] * (_shift(v, 1, 0) - v), self.h) / self.h
        )

    def rhs(self, t: float, u: np.ndarray) -> np.ndarray:
        varying = self._flux(self._faces(u), u) if self.variable else 0.0
        return self.constant(u) + varying + self.forcing(t)

    def jvp(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The derivative of ``K`` at ``u`` along ``v``."""
        out = self._flux(self._faces(u), v)
        if self.model.conductivity is not None:  # the faces' a(T) changes too, by a0 beta (v_i + v_j) / 2
            a0, beta, _ = self.model.conductivity
            gx, gy = _shift(u, 0, 1) - u, _shift(u, 1, 0) - u
            fx, fy = (
                0.5 * a0 * beta * (v + _shift(v, 0, 1)) * gx,
                0.5 * a0 * beta * (v + _shift(v, 1, 0)) * gy,
            )
            out = out + _divergence(fx, fy, self.h) / self.h
        return out

    def solve(self, r: np.ndarray, c: float, t: float, guess: np.ndarray) -> np.ndarray:
        """``u`` with ``u - c F(t, u) = r``: by FFT when ``K`` is zero, else by Newton-GMRES on
        ``z = (I - c C) u``, preconditioned on the right by the exact inverse of the constant part.
        RuntimeError when Newton does not converge."""
        rhs = r + c * self.forcing(t)
        if not self.variable:
            return self.inverse(rhs, c)
        z = guess - c * self.constant(guess)
        for _ in range(_NEWTON_STEPS):
            u = self.inverse(z, c)
            residual = z - c * self._flux(self._faces(u), u) - rhs
            if float(np.abs(residual).max()) <= self.tolerance:
                return u
            step = gmres(lambda v, u=u: v - c * self.jvp(u, self.inverse(v, c)), -residual, self.tolerance)
            z = z + step
        raise RuntimeError(
            f"independent simulator: Newton did not converge in {_NEWTON_STEPS} steps at t={t:.4g} s "
            f"(residual {float(np.abs(residual).max()):.3g}); use more substeps"
        )


def _tr_bdf2(ops: _Operators, u: np.ndarray, t: float, h: float) -> np.ndarray:
    """One TR-BDF2 step of ``h`` s from ``u`` at ``t``: the trapezoid to ``t + gamma h``, then BDF2."""
    c = _STAGE * h
    middle = ops.solve(u + c * ops.rhs(t, u), c, t + _GAMMA * h, u)
    r = (middle / _GAMMA - (1.0 - _GAMMA) ** 2 / _GAMMA * u) / (2.0 - _GAMMA)
    return ops.solve(r, c, t + h, middle)


def _finite_volume(
    model: Continuum, initial: Callable[[Tensor, Tensor], Tensor], domain: _Domain, dt: float, n_frames: int,
    substeps: int,
) -> np.ndarray:  # fmt: skip
    """Frames ``(T, H, W)``: pixel averages of the finite-volume solution, ``substeps`` TR-BDF2 a frame."""
    u = domain.average(initial)
    ops = _Operators(model, domain, (float(u.min()), float(u.max())))
    frames = [domain.pixels(u)]
    h = dt / substeps
    for k in range(n_frames - 1):
        for s in range(substeps):
            u = _tr_bdf2(ops, u, (k + s / substeps) * dt, h)
        frames.append(domain.pixels(u))
    return np.stack(frames)


# ------------------------------------------------------------------------------------------ API
@dataclass(frozen=True)
class ContinuumGrid:
    """How :func:`simulate_continuum` discretises the continuous PDE.

    Attributes:
        pad: camera px of padding on each side, >= 0; None: half the larger frame side.
        refine: finite-volume cells per camera pixel along each axis, >= 1.
        substeps: TR-BDF2 steps per frame of the finite volumes; None: 2.
        method: one of :data:`METHODS`.
    """

    pad: int | None = None
    refine: int = 2
    substeps: int | None = None
    method: str = "auto"

    def checked(self, height: int, width: int) -> tuple[int, int, int, str]:
        """``(pad, refine, substeps, method)`` checked for a ``(height, width)`` px frame, defaults filled.

        Raises:
            ValueError: a negative ``pad``, ``refine`` or ``substeps`` below 1, an unknown ``method``.
        """
        pad = (max(height, width) + 1) // 2 if self.pad is None else check_int(self.pad, "pad", 0)
        refine = check_int(self.refine, "refine", 1)
        substeps = 2 if self.substeps is None else check_int(self.substeps, "substeps", 1)
        return pad, refine, substeps, check_choice(self.method, "method", METHODS)


def simulate_continuum(
    initial: Callable[[Tensor, Tensor], Tensor],
    model: Continuum,
    *,
    shape: tuple[int, int],
    dx: float,
    dt: float,
    n_frames: int,
    grid: ContinuumGrid | None = None,
) -> Tensor:
    """Simulate the continuous PDE ``model`` from a continuous initial field, as a camera sees it.

    Pixel ``(i, j)`` covers ``[j dx, (j + 1) dx] x [i dx, (i + 1) dx]``. The frame lies in a periodic
    domain ``pad`` px wider on each side, which ``initial`` should reach smoothly; with ``pad=0`` it should
    be periodic over the frame. Frame ``k`` is the solution at ``k dt`` averaged over each pixel.

    Args:
        initial: ``T0(x, y)`` at points in mm, float64 tensors that broadcast.
        model: the continuous PDE, :class:`Continuum`.
        shape: frame size ``(H, W)`` in px.
        dx, dt: pixel size in mm and frame period in s.
        n_frames: number of frames, >= 1.
        grid: the padding, refinement, steps and method, :class:`ContinuumGrid`; default ``ContinuumGrid()``.

    Returns:
        The video, float64.

    Shape:
        Output ``(n_frames, H, W)``.

    Raises:
        ValueError: bad sizes or spacings, an ``initial`` not finite over the padded domain,
            ``method="spectral"`` for a model with a heat input or a varying diffusivity, conduction into
            depth beside a heat input, a nonlinear diffusion or another ambient.
        TypeError: an ``initial`` that is not a function.
        RuntimeError: a stage equation that did not converge; more ``substeps`` help.

    Example:
        >>> import math
        >>> k = 2 * math.pi / 16  # one period over a 16 px frame of 1 mm pixels, periodic with pad=0
        >>> video = simulate_continuum(
        ...     lambda x, y: 30 + torch.cos(k * x) + 0 * y, Continuum(tensor=(0.2, 0.2, 0.0)), shape=(8, 16),
        ...     dx=1.0, dt=1.0, n_frames=3, grid=ContinuumGrid(pad=0))
        >>> round(float((video[2, 0].max() - 30) / (video[0, 0].max() - 30)) / math.exp(-0.4 * k * k), 6)
        1.0
    """
    height, width = check_shape(shape)
    dx, dt = number(dx, "dx", "mm", positive=True), number(dt, "dt", "s", positive=True)
    n_frames = check_int(n_frames, "n_frames", 1)
    pad, refine, substeps, method = (ContinuumGrid() if grid is None else grid).checked(height, width)
    _check_model(initial, model, method)
    if model.depth is not None:  # exact: the rest of the model times the plate's depth factor
        grid = ContinuumGrid(pad, refine, substeps, method)
        return _with_plate(initial, model, dict(shape=shape, dx=dx, dt=dt, n_frames=n_frames, grid=grid))
    if method == "finite_volume" or not model.spectral:
        domain = _Domain((height, width), dx, pad, refine)
        return torch.from_numpy(_finite_volume(model, initial, domain, dt, n_frames, substeps))
    samples = _Domain((height, width), dx, pad, 1)
    start = _evaluate(initial, samples.centres(1), samples.centres(0))
    return torch.from_numpy(_spectral(model, start, dx, pad, np.arange(n_frames) * dt))


def _with_plate(initial: Callable[[Tensor, Tensor], Tensor], model: Continuum, settings: dict) -> Tensor:
    """:func:`simulate_continuum` of ``model`` without its conduction into depth, times the plate's exact
    depth factor from :mod:`anra_torch.simulation.plate`; exact for ``T - T_ref`` only when the rest is
    linear and keeps ``T_ref`` where it is. ValueError for a model where it is not."""
    depth = model.depth
    assert depth is not None
    if model.forcings or model.conductivity is not None or (model.loss > 0 and model.ambient != depth[3]):
        raise ValueError(
            "the independent simulator combines conduction into depth only with diffusion, anisotropy, "
            "advection, a heterogeneity or a linear loss to the same T_ref, got a heat input, a nonlinear "
            "diffusion or another ambient"
        )
    clean = simulate_continuum(initial, dataclasses.replace(model, depth=None), **settings)
    return with_depth(clean, np.arange(settings["n_frames"]) * settings["dt"], depth)


def _check_model(initial: Callable[[Tensor, Tensor], Tensor], model: Continuum, method: str) -> None:
    """``initial`` a function, and ``model`` one that ``method`` solves."""
    if not callable(initial):
        raise TypeError(f"initial must be a function T0(x, y) of points in mm, got {type(initial).__name__}")
    if method == "spectral" and not model.spectral:
        raise ValueError(
            "method='spectral' needs constant coefficients and no heat input, got a model with "
            f"{_varying(model)}; use method='finite_volume' or 'auto'"
        )


def _varying(model: Continuum) -> str:
    """What keeps ``model`` from the spectral solution, for a message."""
    parts = ["a heat input"] if model.forcings else []
    parts += ["a diffusivity field"] if model.diffusivity is not None else []
    parts += ["a temperature-dependent diffusivity"] if model.conductivity is not None else []
    return ", ".join(parts)
