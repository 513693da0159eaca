"""Peer estimators of the thermal diffusivity that anra_torch is compared against.

Every peer takes one video ``frames`` of shape ``(T, H, W)`` (float64, any temperature unit), the
frame period ``dt`` (s) and the pixel pitch ``dx`` (mm per px, square pixels), fits the heat
equation ``dT/dt = a (d_xx + d_yy) T`` and returns a :class:`PeerResult` with ``a`` in mm^2/s.

- :func:`spectral_fit`: Problem 1 of El-Kebir et al. (arXiv 2203.13148) solved exactly: least
  squares over ``a`` between the frames and the exact heat-equation solution from the first frame
  on the frame's rectangle (periodic or Neumann). The best a simulate-and-compare method can do,
  but only with the right boundary condition.
- :func:`pde_find_estimate`: PySINDy strong form (PDE-FIND, Rudy et al. 2017).
- :func:`weak_sindy_estimate`: PySINDy weak form (Messenger & Bortz 2021), defaults or tuned.
- :func:`numpy_direct_estimate`: a direct NumPy/SciPy PDE balance (Gaussian smoothing, 5-tap time
  derivative, Laplacian, least squares): the plain-CPU peer for throughput benchmarks.

A peer never raises for a failed fit: it returns ``ok=False`` with the reason in ``note``. Invalid
input (wrong shape, non-positive spacing, non-finite values) raises ``ValueError``.

``seconds`` is the wall time of the whole fit (transforms, derivatives, library assembly and
optimisation; input validation and imports excluded). ``peak_mb`` is the peak memory allocated
during the fit above what was allocated when it started, measured with :mod:`tracemalloc` in a
second run of the same (deterministic) fit, because tracing slows PySINDy ~3x. NumPy and SciPy
arrays are traced; scratch space of C/C++/Fortran internals that bypass Python's allocators
(pocketfft, BLAS/LAPACK workspaces) is not. ``memory=False`` skips that run (``peak_mb = NaN``).
The PySINDy peers run with one BLAS thread by default (``blas_threads``): their thousands of tiny
products only lose from threading, badly so on a busy machine (0.4 s -> 6 s measured).

This module is an experiment helper (``experiments/`` is never imported by the package): scripts and tests
do ``from experiments.peers import spectral_fit, ...`` (run from the repository's folder). It needs
SciPy and, for the SINDy peers, PySINDy (``pip install 'anra_torch[peers]'``).
"""

from __future__ import annotations

import contextlib
import math
import time
import tracemalloc
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.ndimage
from scipy.optimize import minimize_scalar

__all__ = [
    "PEERS",
    "PeerResult",
    "numpy_direct_estimate",
    "paper_video",
    "pde_find_estimate",
    "spectral_fit",
    "weak_sindy_estimate",
]

FitOutcome = tuple[float, bool, str]  # (a in mm^2/s, ok, note)


@dataclass(frozen=True)
class PeerResult:
    """Outcome of one peer fit on one video.

    Attributes:
        name: peer name, e.g. ``"spectral_fit[periodic]"``.
        diffusivity: estimated a (mm^2/s); NaN only when ``ok`` is False.
        seconds: wall time of the fit (s).
        peak_mb: peak extra memory during the fit (MiB), by tracemalloc in a second run (see the
            module docstring); NaN when not measured.
        ok: False when the fit failed (the reason is in ``note``).
        note: what happened, e.g. ``"Laplacian term dropped; kept: ..."``, ``"empty model"``.
    """

    name: str
    diffusivity: float
    seconds: float
    peak_mb: float
    ok: bool
    note: str = ""


# -------------------------------------------------------------------------------------------------
# shared helpers


def _check_video(frames: np.ndarray, dt: float, dx: float, *, min_frames: int) -> np.ndarray:
    frames = np.asarray(frames)
    if frames.ndim != 3:
        raise ValueError(f"frames must have shape (T, H, W), got {frames.shape}")
    if frames.shape[0] < min_frames:
        raise ValueError(f"need at least {min_frames} frames, got {frames.shape[0]}")
    if not np.issubdtype(frames.dtype, np.number) or np.iscomplexobj(frames):
        raise ValueError(f"frames must be real numbers, got dtype {frames.dtype}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite frame period in s, got {dt}")
    if not (np.isfinite(dx) and dx > 0):
        raise ValueError(f"dx must be a positive finite pixel pitch in mm, got {dx}")
    frames = np.ascontiguousarray(frames, dtype=np.float64)
    finite = np.isfinite(frames)
    if not finite.all():
        raise ValueError(
            f"frames must be finite, got {finite.size - int(finite.sum())} non-finite values; "
            "mask or inpaint them first"
        )
    return frames


def _run_fit(fit: Callable[[], FitOutcome]) -> FitOutcome:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            a, ok, note = fit()
    except Exception as err:  # a peer reports a failed fit, never raises (PySINDy raises many types)
        return math.nan, False, f"fit failed: {type(err).__name__}: {err}"
    a = float(a)
    if ok and not math.isfinite(a):
        ok, note = False, f"non-finite estimate; {note}"
    return (a if ok else math.nan), ok, note


def _measured(name: str, fit: Callable[[], FitOutcome], memory: bool) -> PeerResult:
    """Run ``fit`` once under a wall clock and, if ``memory``, once more under tracemalloc for the
    peak (tracing slows allocation-heavy code, so it never overlaps the timed run). The fits are
    deterministic: the second run repeats the first."""
    t0 = time.perf_counter()
    a, ok, note = _run_fit(fit)
    seconds = time.perf_counter() - t0
    peak_mb = math.nan
    if memory:
        started_here = not tracemalloc.is_tracing()
        if started_here:
            tracemalloc.start()
        else:
            tracemalloc.reset_peak()
        base, _ = tracemalloc.get_traced_memory()
        _run_fit(fit)
        _, peak = tracemalloc.get_traced_memory()
        if started_here:
            tracemalloc.stop()
        peak_mb = max(peak - base, 0) / 2**20
    return PeerResult(name, a, seconds, peak_mb, ok, note)


def paper_video(*, noise: float = 0.01, seed: int = 0, **options: object) -> tuple[np.ndarray, float, float]:
    """One video of the paper's case as NumPy ``(frames (T, H, W), dt, dx)``, from
    :func:`anra_torch.simulation.paper_video`.

    ``options`` go to :func:`anra_torch.simulation.paper_video` (e.g. ``crop``, ``fps``, ``a``).
    """
    from anra_torch.simulation.synthetic import paper_video as make

    video = make(n_videos=1, seed=seed, noise_sd=noise, **options)
    return video.frames[0].numpy(), video.dt, video.dx


# -------------------------------------------------------------------------------------------------
# 1. spectral fit: Problem 1 with the exact solution on the frame's rectangle

_BOUNDARIES = ("periodic", "neumann")


def _spectral_modes(frames: np.ndarray, dx: float, boundary: str) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal transforms of all frames as (T, Q) coefficients, Parseval weights folded in, and
    the Laplacian eigenvalue |k|^2 (1/mm^2) of each of the Q modes."""
    n_t, h, w = frames.shape
    if boundary == "periodic":
        # Real FFT over x: every column except 0 (and W/2 for even W) stands for itself and its
        # conjugate, so it counts twice in Parseval's sum.
        coef = scipy.fft.rfft2(frames, axes=(1, 2), norm="ortho")
        ky = 2 * np.pi * np.fft.fftfreq(h, dx)
        kx = 2 * np.pi * np.fft.rfftfreq(w, dx)
        weight = np.full(kx.size, 2.0)
        weight[0] = 1.0
        if w % 2 == 0:
            weight[-1] = 1.0
        coef *= np.sqrt(weight)
    else:
        # DCT-II basis functions are the Neumann eigenfunctions cos(pi m x / (n dx)) sampled at the
        # pixel centres (j + 0.5) dx: insulated edges at the outer pixel borders.
        coef = scipy.fft.dctn(frames, type=2, axes=(1, 2), norm="ortho")
        ky = np.pi * np.arange(h) / (h * dx)
        kx = np.pi * np.arange(w) / (w * dx)
    k2 = ky[:, None] ** 2 + kx[None, :] ** 2
    return coef.reshape(n_t, -1), k2.reshape(-1)


def spectral_fit(
    frames: np.ndarray,
    dt: float,
    dx: float,
    *,
    boundary: str = "periodic",
    bounds: tuple[float, float] = (1e-4, 10.0),
    memory: bool = True,
) -> PeerResult:
    """Problem 1 solved exactly: ``argmin_a sum_k ||T[k] - Tbar_a(k dt)||^2``.

    ``Tbar_a(t)`` is the exact heat-equation solution on the frame's rectangle from ``T[0]``: each
    mode of ``T[0]`` decays as ``exp(-a |k|^2 t)``. ``boundary="periodic"`` uses the FFT with
    continuous wavenumbers ``k = 2 pi fftfreq(n, dx)``; ``"neumann"`` (insulated edges) uses the
    orthonormal DCT-II with eigenvalues ``(pi m / (n dx))^2`` per axis. All frames are transformed
    once; by Parseval the objective is a sum over modes,
    ``J(a) = sum_k sum_q |c_k(q) - c_0(q) exp(-a |k_q|^2 t_k)|^2``, expanded into per-mode sums
    with modes of equal ``|k|^2`` merged, so an evaluation costs ``(T - 1) x (distinct |k|^2)``
    exponentials. ``J`` is minimised over ``log a`` in ``bounds`` by bounded Brent (``xatol=1e-9``).

    Exact only when the frame's rectangle with that boundary condition is the true domain; on a
    crop of a larger field heat crossing the crop's edges is misread and a is biased (low).

    Args:
        frames: video, shape ``(T, H, W)``, frame k taken at ``k dt``.
        dt: frame period (s).
        dx: pixel pitch (mm).
        boundary: ``"periodic"`` or ``"neumann"``.
        bounds: search interval for a (mm^2/s); a minimum on a bound is reported as ``ok=False``.
        memory: also measure ``peak_mb`` (a second, traced run); False gives NaN.

    Returns:
        PeerResult named ``spectral_fit[<boundary>]``; ``note`` gives the relative RMS residual.

    Raises:
        ValueError: bad shape, spacing, boundary or bounds.

    Shape:
        frames ``(T, H, W)``, ``T >= 2``.

    Example:
        >>> frames, dt, dx = paper_video(noise=0.0, size=64, fwhm_px=12.0)
        >>> round(spectral_fit(frames, dt, dx).diffusivity, 4)
        0.2
    """
    frames = _check_video(frames, dt, dx, min_frames=2)
    if boundary not in _BOUNDARIES:
        raise ValueError(f"unknown boundary {boundary!r}; expected one of: {', '.join(_BOUNDARIES)}")
    lo, hi = (float(b) for b in bounds)
    if not (0 < lo < hi < math.inf):
        raise ValueError(f"bounds must satisfy 0 < low < high < inf, got {bounds}")

    def fit() -> FitOutcome:
        coef, k2 = _spectral_modes(frames, dx, boundary)
        c0, ck = coef[0], coef[1:]
        # J(a) = sum |ck|^2 - 2 sum Re(ck conj(c0)) e^{-a k2 t} + sum |c0|^2 e^{-2 a k2 t}. Modes
        # of equal |k|^2 (repeated by the grid's symmetries) share the decay: sum them first.
        key = np.round(k2 * (dx * dx) * 1e9).astype(np.int64)
        _, inverse = np.unique(key, return_inverse=True)
        n_u = int(inverse.max()) + 1
        k2u = np.bincount(inverse, weights=k2, minlength=n_u) / np.bincount(inverse, minlength=n_u)
        cross = np.real(ck * np.conj(c0))
        cross = np.stack([np.bincount(inverse, weights=row, minlength=n_u) for row in cross])
        power0 = np.bincount(inverse, weights=np.abs(c0) ** 2, minlength=n_u)
        total = float(np.sum(np.abs(ck) ** 2))
        if not np.any(power0[k2u > 0] > 0):
            return math.nan, False, "first frame has no spatial variation: J does not depend on a"
        t = dt * np.arange(1, frames.shape[0])[:, None]

        def objective(log_a: float) -> float:
            decay = np.exp(-math.exp(log_a) * k2u[None, :] * t)
            return total - 2.0 * float(np.sum(cross * decay)) + float(np.sum(power0 * decay**2))

        res = minimize_scalar(
            objective,
            bounds=(math.log(lo), math.log(hi)),
            method="bounded",
            options={"xatol": 1e-9, "maxiter": 500},
        )
        a = math.exp(res.x)
        rel_rms = math.sqrt(max(res.fun, 0.0) / max(total, np.finfo(float).tiny))
        note = f"relative RMS residual {rel_rms:.3g}, {res.nfev} evaluations"
        if not res.success:
            return a, False, f"minimize_scalar failed: {res.message}; {note}"
        if min(res.x - math.log(lo), math.log(hi) - res.x) < 1e-6:
            return a, False, f"minimum on a bound ({a:.4g}) of {bounds}; {note}"
        return a, True, note

    return _measured(f"spectral_fit[{boundary}]", fit, memory)


# -------------------------------------------------------------------------------------------------
# 2, 3. PySINDy peers (strong and weak form)


def _import_pysindy():
    try:
        import pysindy
    except ImportError as err:  # pragma: no cover - depends on the environment
        raise ImportError(
            "the SINDy peers need PySINDy: pip install 'anra_torch[peers]' (pysindy>=2.1)"
        ) from err
    return pysindy


def _blas_limit(blas_threads: int | None) -> contextlib.AbstractContextManager:
    if blas_threads is None:
        return contextlib.nullcontext()
    from threadpoolctl import threadpool_limits  # a dependency of scikit-learn, hence of PySINDy

    return threadpool_limits(limits=blas_threads, user_api="blas")


def _laplacian_from_model(model, scale: float) -> FitOutcome:
    """``a`` = mean coefficient of x0_11 and x0_22 of a fitted SINDy model, times ``scale``."""
    names = list(model.get_feature_names())
    coef = np.asarray(model.coefficients(), dtype=np.float64).reshape(-1)
    kept = [f"{c:+.4g} {n}" for n, c in zip(names, coef, strict=True) if c != 0.0]
    if not kept:
        return math.nan, False, "empty model (every term thresholded away)"
    kept_txt = "kept: " + ", ".join(kept)
    missing = [n for n in ("x0_11", "x0_22") if n not in names]
    if missing:
        return math.nan, False, f"library lacks {', '.join(missing)}; features are {names}"
    c11, c22 = coef[names.index("x0_11")], coef[names.index("x0_22")]
    if c11 == 0.0 and c22 == 0.0:
        return math.nan, False, f"Laplacian term dropped; {kept_txt}"
    if c11 == 0.0 or c22 == 0.0:
        dropped = "x0_11" if c11 == 0.0 else "x0_22"
        return math.nan, False, f"half of the Laplacian ({dropped}) dropped; {kept_txt}"
    return 0.5 * (c11 + c22) * scale, True, kept_txt


def _grid(*axes: np.ndarray) -> np.ndarray:
    """Coordinate grid of shape ``(*lengths, n_axes)``; component i varies along axis i."""
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)


def pde_find_estimate(
    frames: np.ndarray,
    dt: float,
    dx: float,
    *,
    threshold: float = 0.1,
    max_samples: int = 4_000_000,
    blas_threads: int | None = 1,
    memory: bool = True,
) -> PeerResult:
    """PySINDy strong form (PDE-FIND): sparse regression of u_t on finite-difference terms.

    PySINDy 2.1 defaults apart from the library: ``ps.PDELibrary`` with
    ``function_library=PolynomialLibrary(degree=1, include_bias=False)`` (the term u),
    ``derivative_order=2``, ``include_bias=True``: features 1, u, u_1, u_2, u_11, u_12, u_22 and u
    times each derivative; derivatives by PySINDy's default finite differences (2nd order, time
    and space); ``STLSQ(threshold=0.1, alpha=0.05)``; physical units (mm, s). Library axis 1 is y
    (along H), axis 2 is x (along W): ``a`` is the mean coefficient of ``x0_11`` and ``x0_22``,
    and the fit is ``ok`` only if both are kept. Noiseless it recovers a to ~0.04 %; at noise sd
    0.01 on the paper's case the Laplacian is dropped (the 5-point Laplacian's noise, ~4.5 sd /
    dx^2 ~ 22 /mm^2 there, swamps the signal's ~4 /mm^2).

    Args:
        frames: video, shape ``(T, H, W)``.
        dt: frame period (s).
        dx: pixel pitch (mm).
        threshold: STLSQ threshold (in the coefficients' units: mm^2/s, 1/s, ...).
        max_samples: above ``T H W`` voxels the pixels are strided by an integer step in both
            directions (the grid's spacing grows to match; the note says so) to bound memory,
            which is ~570 B per voxel (800 MB for 224 x 224 x 28).
        blas_threads: BLAS threads during the fit (None leaves the pool alone).
        memory: also measure ``peak_mb`` (a second, traced run); False gives NaN.

    Returns:
        PeerResult named ``pde_find``; ``note`` lists the kept terms.

    Raises:
        ValueError: bad shape or spacing, fewer than 3 frames or 3 x 3 pixels.
        ImportError: PySINDy missing.

    Shape:
        frames ``(T, H, W)``, ``T >= 3``.
    """
    frames = _check_video(frames, dt, dx, min_frames=3)
    if min(frames.shape[1:]) < 3:
        raise ValueError(f"frames must be at least 3 x 3 px, got {frames.shape[1:]}")
    ps = _import_pysindy()

    def fit() -> FitOutcome:
        step = max(1, math.ceil(math.sqrt(frames.size / max_samples)))
        video, h = frames[:, ::step, ::step], dx * step
        n_t, n_y, n_x = video.shape
        grid = _grid((np.arange(n_y) + 0.5) * h, (np.arange(n_x) + 0.5) * h)
        u = np.moveaxis(video, 0, -1)[..., None]  # PySINDy's layout (y, x, t, coordinate)
        library = ps.PDELibrary(
            function_library=ps.PolynomialLibrary(degree=1, include_bias=False),
            derivative_order=2,
            spatial_grid=grid,
            include_bias=True,
        )
        model = ps.SINDy(feature_library=library, optimizer=ps.STLSQ(threshold=threshold))
        with _blas_limit(blas_threads):
            model.fit(u, t=dt * np.arange(n_t))
        a, ok, note = _laplacian_from_model(model, 1.0)
        if step > 1:
            note = f"pixels strided by {step} for memory; {note}"
        return a, ok, note

    return _measured("pde_find", fit, memory)


# Tuned weak-SINDy settings (see weak_sindy_estimate), in pixel and frame units.
_WEAK_K = 200
_WEAK_HALF_WIDTH = (22.0, 22.0, 7.0)  # y (px), x (px), t (frames)
_WEAK_MAX_FRACTION = 0.4  # half-widths are clipped to this fraction of the video's extent
_WEAK_THRESHOLD = 0.1


def weak_sindy_estimate(
    frames: np.ndarray,
    dt: float,
    dx: float,
    *,
    tuned: bool = True,
    seed: int = 0,
    blas_threads: int | None = 1,
    memory: bool = True,
) -> PeerResult:
    """PySINDy weak form (weak SINDy): sparse regression of integrals against test functions.

    ``tuned=False`` is PySINDy 2.1's defaults with a second-order spatial library:
    ``ps.WeakPDELibrary`` with its default function library (PolynomialLibrary degree 3: u, u^2,
    u^3), ``derivative_order=2``, ``include_interaction=True``, ``K=100`` subdomains of
    half-width ``H_xt = L_xt / 20`` (0.5 mm and 0.05 s ~ 1.4 frames on the paper's case),
    test-function degree ``p=4``, ``STLSQ(threshold=0.1, alpha=0.05)``, physical units (mm, s).
    On the paper's case it returns an empty model, at noise 0.01 and also noiseless.

    ``tuned=True`` (chosen on the paper's case, a = 0.2 and 0.05 mm^2/s, noise 0.01, 4 seeds):

    - pixel and frame units (grid spacing 1 in y, x, t), so the Laplacian's coefficient is
      ``a dt / dx^2`` (3.7 on the paper's case, 0.9 at a = 0.05): O(1) for thermography, which
      gives the absolute STLSQ threshold a meaning; ``a = coefficient * dx^2 / dt``;
    - library u, u_1, u_2, u_11, u_12, u_22 (``PolynomialLibrary(degree=1,
      include_bias=False)``, ``include_interaction=False``);
    - ``K=200`` subdomains of half-width 22 px in y and x and 7 frames in t (each clipped to 0.4
      of the video's extent along its axis, so crops and short videos still work), ``p=4``;
    - ``STLSQ(threshold=0.1, alpha=0.05)``.

    Measured at noise 0.01 on 224 x 224 x 28 with one BLAS thread: within 0.2 % for a = 0.2 and
    a = 0.05, exactly the two Laplacian terms kept, ~0.7 s. K=100 halves the time at up to ~1 %
    error; 15 px half-widths double the error; at threshold 0.01 in physical units a spurious u
    term appears; the default ``L/20`` half-widths lose the Laplacian.

    PySINDy draws the subdomain centres from NumPy's global generator; it is seeded with ``seed``
    for the fit and its previous state restored afterwards.

    Args:
        frames: video, shape ``(T, H, W)``.
        dt: frame period (s).
        dx: pixel pitch (mm).
        tuned: tuned settings (True) or PySINDy defaults (False).
        seed: seed of the subdomain centres.
        blas_threads: BLAS threads during the fit (None leaves the pool alone).
        memory: also measure ``peak_mb`` (a second, traced run); False gives NaN.

    Returns:
        PeerResult named ``weak_sindy[tuned]`` or ``weak_sindy[default]``; ``note`` gives the
        settings and the kept terms.

    Raises:
        ValueError: bad shape or spacing, fewer than 5 frames or 5 x 5 pixels.
        ImportError: PySINDy missing.

    Shape:
        frames ``(T, H, W)``, ``T >= 5``.
    """
    frames = _check_video(frames, dt, dx, min_frames=5)
    if min(frames.shape[1:]) < 5:
        raise ValueError(f"frames must be at least 5 x 5 px, got {frames.shape[1:]}")
    ps = _import_pysindy()
    n_t, n_y, n_x = frames.shape
    u = np.moveaxis(frames, 0, -1)[..., None]  # PySINDy's layout (y, x, t, coordinate)

    def fit() -> FitOutcome:
        if tuned:
            extent = np.array([n_y - 1, n_x - 1, n_t - 1], dtype=np.float64)
            half = np.minimum(np.array(_WEAK_HALF_WIDTH), _WEAK_MAX_FRACTION * extent)
            grid = _grid(np.arange(n_y, dtype=float), np.arange(n_x, dtype=float), np.arange(n_t))
            library_kw = {
                "function_library": ps.PolynomialLibrary(degree=1, include_bias=False),
                "include_interaction": False,
                "K": _WEAK_K,
                "H_xt": half,
            }
            threshold, scale = _WEAK_THRESHOLD, dx * dx / dt
            setting = f"K={_WEAK_K}, H_xt=({half[0]:g} px, {half[1]:g} px, {half[2]:g} frames)"
        else:
            grid = _grid((np.arange(n_y) + 0.5) * dx, (np.arange(n_x) + 0.5) * dx, np.arange(n_t) * dt)
            library_kw, threshold, scale, setting = {}, 0.1, 1.0, "PySINDy defaults"
        saved = np.random.get_state()  # noqa: NPY002 - PySINDy samples from the global generator
        np.random.seed(seed)  # noqa: NPY002
        try:
            library = ps.WeakPDELibrary(derivative_order=2, spatiotemporal_grid=grid, **library_kw)
            model = ps.SINDy(feature_library=library, optimizer=ps.STLSQ(threshold=threshold))
            with _blas_limit(blas_threads):
                model.fit(u, t=grid[0, 0, :, 2])
        finally:
            np.random.set_state(saved)  # noqa: NPY002
        a, ok, note = _laplacian_from_model(model, scale)
        return a, ok, f"{setting}; {note}"

    return _measured("weak_sindy[tuned]" if tuned else "weak_sindy[default]", fit, memory)


# -------------------------------------------------------------------------------------------------
# 4. direct NumPy/SciPy estimator

_DT5 = np.array([-1.0, -2.0, 0.0, 2.0, 1.0]) / 8.0  # Holoborodko N=5, oldest frame first


def numpy_direct_estimate(
    frames: np.ndarray, dt: float, dx: float, *, sigma: float = 4.0, memory: bool = True
) -> PeerResult:
    """Direct PDE balance in plain NumPy/SciPy: the CPU peer for throughput benchmarks.

    1. ``S[k] = gaussian_filter(T[k], sigma)`` for every frame (spatial only, ``sigma`` in px);
    2. ``U_t[k] = sum_j w_j S[k + j] / dt``, ``w = [-1, -2, 0, 2, 1] / 8`` on ``j = -2 .. 2``,
       for the frames ``k = 2 .. T - 3`` that have both neighbours;
    3. ``L[k] = scipy.ndimage.laplace(S[k]) / dx^2`` of the same (centre) frame;
    4. crop ``ceil(4 sigma)`` px from every border (the smoothing's 'valid' region) and
       ``a = sum(U_t L) / sum(L^2)``.

    The same spatial smoothing on both sides keeps the linear PDE exact for the smoothed field, so
    sigma lowers the noise without biasing a (up to the 5-point Laplacian's truncation error).

    Args:
        frames: video, shape ``(T, H, W)``.
        dt: frame period (s).
        dx: pixel pitch (mm).
        sigma: Gaussian smoothing width (px).
        memory: also measure ``peak_mb`` (a second, traced run); False gives NaN.

    Returns:
        PeerResult named ``numpy_direct``; ``note`` gives the number of samples used.

    Raises:
        ValueError: bad shape or spacing, fewer than 5 frames, or frames too small for the crop.

    Shape:
        frames ``(T, H, W)``, ``T >= 5``, ``H, W > 2 ceil(4 sigma) + 2``.
    """
    frames = _check_video(frames, dt, dx, min_frames=5)
    if not (math.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive width in px, got {sigma}")
    m = math.ceil(4 * sigma)
    if min(frames.shape[1:]) <= 2 * m + 2:
        raise ValueError(
            f"frames of {frames.shape[1]} x {frames.shape[2]} px leave nothing after cropping "
            f"{m} px (4 sigma) from each border; use a smaller sigma or larger frames"
        )

    def fit() -> FitOutcome:
        smooth = scipy.ndimage.gaussian_filter(frames, sigma=(0.0, sigma, sigma))
        n = frames.shape[0] - 4
        u_t = sum(w * smooth[j : j + n] for j, w in enumerate(_DT5) if w != 0.0) / dt
        lap = np.empty_like(u_t)
        for k in range(n):
            scipy.ndimage.laplace(smooth[k + 2], output=lap[k])
        lap /= dx * dx
        u_t, lap = u_t[:, m:-m, m:-m], lap[:, m:-m, m:-m]
        denom = float(np.vdot(lap, lap))
        if not denom > 0:
            return math.nan, False, "Laplacian identically zero: the video carries no information"
        return float(np.vdot(u_t, lap)) / denom, True, f"{lap.size} samples, sigma {sigma:g} px"

    return _measured("numpy_direct", fit, memory)


PEERS: dict[str, Callable[..., PeerResult]] = {
    "spectral_fit": spectral_fit,
    "pde_find": pde_find_estimate,
    "weak_sindy": weak_sindy_estimate,
    "numpy_direct": numpy_direct_estimate,
}
"""Registry: peer name -> ``fn(frames, dt, dx, **options) -> PeerResult``."""
