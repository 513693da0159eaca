"""A camera's static fixed pattern in a forecast: each model's per-pixel fixed effects, carried forward.

A static pattern ``P`` (per-pixel offsets, column stripes) sits in every frame. The balance removes it exactly
with per-pixel fixed effects in every model it fits. A forecast starts from a state that holds ``P``; the
model diffuses it while the measured frames keep it, so ``P`` makes most of every model's forecast error and
two models are compared by how each smooths it. Scoring each pixel's errors about their mean removes ``P``
but also most of a wrong model's error (set in the starting state, nearly constant at each pixel over the
forecast: a true anisotropy of 35 % of ``dT/dt`` cost 0.04 noise floors that way, 13.6 scored plainly
on the clean video).

:func:`pixel_forcing` is the model's own per-pixel fixed effects, measured on the frames it was fitted to:
the mean over them of its one-frame residual ``(y[t + 1] - M(y[t])) / dt`` (``M``: the model one frame
ahead, bounded by the measured ring). For a static ``P`` and a linear model this is ``(I - M) P / dt``, so
the model forecast with it as a stationary heat input keeps ``P`` where the camera keeps it, whatever the
model's operator (anisotropic, heterogeneous, advective), to first order in the step: at a 2 px evaluation
scale a white pattern is held within 3.3 % over 8 frames (55 % is lost without it; a constant input
smooths the pattern's roughest part within a step, which that scale hardly sees). Each model has its own,
as in the balance: what the input also absorbs is the model's mean misfit over its fit frames, so an effect
is judged by what it does to the forecast beyond a constant rate at each pixel
(``tests/forecast/test_pattern.py``).
"""

from __future__ import annotations

import torch
from torch import Tensor

from anra_torch.effects import EFFECTS
from anra_torch.forecast.core import extended_effects, simulate_model
from anra_torch.selection import Diagnosis

__all__ = ["pixel_forcing"]

_CHUNK_PIXELS = 2**21  # pixels per batched step: 16 MB per float64 field of the integrator


def pixel_forcing(frames: Tensor, model: Diagnosis, dt: float, dx: float) -> Tensor:
    """The per-pixel fixed effects of ``model`` on ``frames`` as a stationary heat input, 0 on the outer ring.

    Args:
        frames: the frames ``model`` was fitted to (float).
        model: a fitted diagnosis (:func:`~anra_torch.selection.fit_effects`).
        dt: frame period in s.
        dx: pixel size in mm.

    Returns:
        The mean one-frame residual in data units per s (the ``forcing`` of
        :func:`~anra_torch.forecast.simulate_model`).

    Raises:
        ValueError: a model that cannot be simulated (as :func:`~anra_torch.forecast.simulate_model`).

    Shape:
        ``frames`` ``(T, H, W)`` with ``T >= 2``; output ``(H, W)``.
    """
    steps = frames.shape[0] - 1
    total = torch.zeros_like(frames[0])
    if not any(EFFECTS[name].retime is not None for name in model.names):  # many steps at once
        chunk = max(1, _CHUNK_PIXELS // frames[0].numel())
        for start in range(0, steps, chunk):  # bounded memory: a camera's large frames a few at a time
            stop = min(start + chunk, steps)
            pairs = torch.stack([frames[start:stop], frames[start + 1 : stop + 1]], 1)
            ahead = simulate_model(frames[start:stop], model, dt=dt, dx=dx, n_frames=2, edges=pairs)[:, 1]
            total += (frames[start + 1 : stop + 1] - ahead).sum(0)
        return total / (steps * dt)
    for t in range(steps):  # a moving source is where its path puts it at each frame
        effects = extended_effects(model, fit_duration=steps * dt, start=t * dt, duration=dt)
        ahead = simulate_model(
            frames[t], model, dt=dt, dx=dx, n_frames=2, effects=effects, edges=frames[t : t + 2]
        )
        total += frames[t + 1] - ahead[1]
    return total / (steps * dt)
