"""Is the finite-volume reference of ``experiments/damage_depth.py`` converged where the experiment uses it?

Two checks on the experiment's own scenes (:func:`anra_torch.simulation.random_scene`, camera noise 0.3 K
seeded as the experiment seeds it):

* the block's lateral margin (its walls hold the heat in): the depth fit's ``a``, ``b`` and ``h / k`` on the
  frames simulated with the tissue 2 mm beyond the view, 6 mm or the scene's own margin (the heat's reach
  ``sqrt(4 a duration)``), and 10 mm, and the damage depth's median change from the 2 mm block;
* the time step: the damage depth under every damaged pixel at steps 0.1 s (the solver's default) down to
  0.0125 s, against the finest.

    python -m experiments.depth_reference_convergence     # about 10 min of one core
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from anra_torch.simulation import random_scene, simulate_bioheat
from anra_torch.tissue import fit_depth_parameters

# contact probes of 74 and 49 s, a laser spot of 70 s: margins in mm (None: the scene's own, the heat's reach)
MARGIN_SCENES = {14: (2.0, 6.0, 10.0), 17: (2.0, 6.0, 10.0), 9: (2.0, None, 10.0)}
STEP_SCENES = {2: (0.1, 0.05, 0.025, 0.0125), 7: (0.1, 0.025)}  # a contact probe, a sweeping tip


def margins() -> None:
    print("| scene | margin (mm) | fitted a (true) | fitted b (true) | h/k (0.02) | truth's median change |")
    print("|---|---|---|---|---|---|")
    for seed, chosen in MARGIN_SCENES.items():
        scene, first = random_scene(seed), None
        t = scene.tissue
        for margin in (scene.margin if m is None else m for m in chosen):
            result = simulate_bioheat(dataclasses.replace(scene, margin=margin))
            rng = np.random.default_rng(10_000 + seed)
            frames = result.frames + 0.3 * rng.standard_normal(result.frames.shape)
            fit = fit_depth_parameters(torch.from_numpy(frames), result.dt, result.dx, body_temperature=37.0)
            first = result.damage_depth if first is None else first
            moved = np.median(np.abs(result.damage_depth - first)[first > 0])
            a, b, beta = (float(v) for v in (fit.diffusivity, fit.loss_rate, fit.surface_loss))
            print(
                f"| {scene.label} {seed} | {margin:.2f} | {a:.4f} ({t.diffusivity:.4f}) | {b:.4f} "
                f"({t.perfusion:.4f}) | {beta:.4f} | {moved:.4f} mm |"
            )


def steps() -> None:
    print("\n| scene | step (s) | damage depth against the finest step: median, 90 %, max (mm) |")
    print("|---|---|---|")
    for seed, chosen in STEP_SCENES.items():
        scene = random_scene(seed)
        depth = {h: simulate_bioheat(scene, step=h).damage_depth for h in chosen}
        finest = depth[chosen[-1]]
        for h in chosen[:-1]:
            change = (depth[h] - finest)[finest > 0]
            quantiles = np.quantile(np.abs(change), [0.5, 0.9, 1.0])
            print(f"| {scene.label} {seed} | {h:g} | " + ", ".join(f"{q:.4f}" for q in quantiles) + " |")


def main() -> None:
    torch.set_num_threads(1)
    margins()
    steps()


if __name__ == "__main__":
    main()
