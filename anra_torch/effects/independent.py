"""A scene's effects simulated independently: each effect's continuous model, solved by another solver.

:func:`simulate_independent` turns effects into the continuous PDE of
:class:`~anra_torch.simulation.Continuum` (each effect module's
:attr:`~anra_torch.effects.EffectSpec.continuum`: what its parameters mean, none of its operators) and solves
it with :func:`~anra_torch.simulation.simulate_continuum`, spectral or finite volumes on a finer
grid, imaged as pixel averages. :func:`independent_effect_video` does so for the scene that
:func:`~anra_torch.effects.hidden_effect_video` draws for a seed: same hot spots, parameters and noise.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

from torch import Tensor

from anra_torch.checks import number
from anra_torch.effects.base import Grid
from anra_torch.effects.model import Effect, check_effects
from anra_torch.effects.registry import EFFECTS
from anra_torch.effects.scene import HiddenEffectVideo, Medium, Scene, Sensor, draw_scene
from anra_torch.simulation import Continuum, ContinuumGrid, simulate_continuum

__all__ = ["continuum_of", "independent_effect_video", "simulate_independent", "simulate_scene"]


def continuum_of(effects: Sequence[Effect], a: float, grid: Grid) -> Continuum:
    """The continuous PDE of ``dT/dt = a Lap T + effects`` on ``grid`` (its ``dx`` and ``duration``).

    Raises:
        ValueError: an effect without a continuous model (naming those that have one).
    """
    model = Continuum(tensor=(a, a, 0.0))
    for effect in effects:
        fill = EFFECTS[effect.name].continuum
        if fill is None:
            known = ", ".join(name for name, spec in EFFECTS.items() if spec.continuum is not None)
            raise ValueError(
                f"the independent simulator has no continuous model of effect {effect.name!r}; "
                f"expected one of: {known}"
            )
        fill(effect.params, model, grid)
    return model


def simulate_independent(
    initial: Callable[[Tensor, Tensor], Tensor],
    *,
    shape: tuple[int, int],
    a: float,
    dx: float,
    dt: float,
    n_frames: int,
    effects: Sequence[Effect] = (),
    grid: ContinuumGrid | None = None,
) -> Tensor:
    """Simulate ``dT/dt = a Lap T + effects`` from a continuous initial field, as a camera sees it.

    The effects' continuous models (:func:`continuum_of`) solved by
    :func:`~anra_torch.simulation.simulate_continuum` (see there for the frame, the padding and
    the methods; ``depth_conduction``: the plate's exact factor).

    Args:
        initial: ``T0(x, y)`` at points in mm (float64 tensors that broadcast).
        shape: frame size ``(H, W)`` in px.
        a: base diffusivity in mm^2/s (>= 0; unused when an effect replaces the diffusion term).
        dx: pixel size in mm.
        dt: frame period in s.
        n_frames: number of frames, >= 1.
        effects: distinct :class:`~anra_torch.effects.Effect` s, at most one replacing diffusion.
        grid: the discretisation (:class:`~anra_torch.simulation.ContinuumGrid`); default ``ContinuumGrid()``.

    Returns:
        The video, float64, ``(n_frames, H, W)``.

    Shape:
        Output ``(n_frames, H, W)``.

    Raises:
        ValueError: bad sizes or spacings, effects without a continuous model, ``method="spectral"`` for
            a model with a source or a varying diffusivity.
        RuntimeError: a stage equation that did not converge (more ``substeps`` help).
    """
    a = number(a, "a", "mm^2/s", minimum=0.0)
    dx = number(dx, "dx", "mm", positive=True)
    dt = number(dt, "dt", "s", positive=True)
    duration = (n_frames - 1) * dt if isinstance(n_frames, int) and n_frames >= 1 else 0.0
    model = continuum_of(check_effects(effects), a, Grid(tuple(shape), dx, duration))
    return simulate_continuum(initial, model, shape=shape, dx=dx, dt=dt, n_frames=n_frames, grid=grid)


def simulate_scene(scene: Scene, *, grid: ContinuumGrid | None = None) -> Tensor:
    """The clean video of a drawn :class:`~anra_torch.effects.scene.Scene`, simulated independently.

    :func:`simulate_independent` from the scene's continuous first field (its hot spots on the background),
    with its effects, pixel size and frames; ``grid`` as there.

    Shape:
        Output ``(n_frames, H, W)`` float64, the scene's frame size.
    """
    if not isinstance(scene, Scene):
        raise TypeError(
            f"scene must be a Scene (anra_torch.effects.scene.draw_scene), got {type(scene).__name__}"
        )
    height, width = scene.initial.shape
    return simulate_independent(
        scene.temperature,
        shape=(height, width),
        a=scene.a,
        dx=scene.dx,
        dt=scene.dt,
        n_frames=scene.n_frames,
        effects=scene.effects,
        grid=grid,
    )


def independent_effect_video(
    effect_names: Sequence[str] | str = (),
    *,
    seed: int,
    size: int = 96,
    dx: float = 0.5,
    fps: float = 30.0,
    duration: float = 3.0,
    medium: Medium | None = None,
    sensor: Sensor | None = None,
    params: Mapping[str, Mapping[str, float]] | None = None,
    grid: ContinuumGrid | None = None,
) -> HiddenEffectVideo:
    """The scene of :func:`anra_torch.effects.hidden_effect_video` for ``seed``, simulated independently.

    Same hot spots, effect parameters and noise draw as the library's video (both come from
    :func:`anra_torch.effects.scene.draw_scene`), solved by :func:`simulate_scene` and imaged as pixel
    averages. The truth (``effects``, ``a``, ``a_map``) is the library's record of the same scene.

    Args:
        effect_names, seed, size, dx, fps, duration, medium, sensor, params: as
            :func:`anra_torch.effects.hidden_effect_video` (``duration`` in s gives ``round(duration * fps)
            + 1`` frames; :class:`~anra_torch.effects.Sensor`: the noise and dtype).
        grid: the discretisation (:class:`~anra_torch.simulation.ContinuumGrid`): padding (default half
            the frame), finite-volume cells per pixel, TR-BDF2 steps per frame (default 2).

    Returns:
        A :class:`~anra_torch.effects.HiddenEffectVideo`.

    Shape:
        ``frames`` ``(T, size, size)``.

    Raises:
        ValueError: as :func:`anra_torch.effects.hidden_effect_video` and :func:`simulate_independent`.

    Example:
        >>> video = independent_effect_video(["advection"], seed=1, size=32, duration=0.5)
        >>> tuple(video.frames.shape), [e.name for e in video.effects]
        ((16, 32, 32), ['advection'])
    """
    sensor = (Sensor() if sensor is None else sensor).checked()  # before the simulation
    drawn = {"seed": seed, "size": size, "dx": dx, "fps": fps, "duration": duration}
    scene = draw_scene(effect_names, **drawn, medium=medium, params=params)
    clean = simulate_scene(scene, grid=grid)
    return scene.video(clean, sensor=sensor)
