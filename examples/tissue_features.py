"""Tissue-damage features of a heated spot: thermal dose, damage integral and the ANRA maps.

A Gaussian tip heats tissue at 37 C for 2 s (the Pennes-like model of
:func:`anra_torch.simulation.simulate_tissue`, with perfusion), then the tissue cools; a 10 Hz camera (4 s)
adds 0.2 K of noise. :class:`anra_torch.TissueFeatures` turns the frames into per-pixel maps (CEM43 in
minutes, the Arrhenius damage integral Omega, time above 43 C, heating and cooling rates, local
diffusivity and loss rate) and per-video summaries; Omega >= 1 marks irreversible damage (skin constants
by default).

    python examples/tissue_features.py
"""

import torch

from anra_torch import TissueFeatures
from anra_torch.simulation import MovingSource, simulate_tissue

torch.manual_seed(0)
size, dx, dt = 40, 0.2, 0.1  # px, mm, s
source = MovingSource(start=(4.0, 4.0), end=(4.0, 4.0), width=0.8, power=20.0, t_on=0.0, t_off=2.0)
initial = torch.full((size, size), 37.0, dtype=torch.float64)
frames = simulate_tissue(initial, 0.14, 0.1, dx=dx, dt=dt, n_frames=40, source=source)  # (T, H, W) in degC
frames = frames + 0.2 * torch.randn_like(frames)

maps = TissueFeatures()(frames, dt, dx)
print("maps:", ", ".join(f"{k} [{maps.units[k]}]" for k in maps.maps))
omega = maps.maps["omega"]
peak, cem43 = float(maps.summary["peak_temperature_max"]), float(maps.summary["cem43_minutes_max"])
print(f"peak {peak:.1f} C, CEM43 max {cem43:.1f} min")
print(
    f"damaged (Omega >= 1): {int((omega >= 1).sum())} of {omega.numel()} px, "
    f"{float((omega >= 1).sum()) * dx**2:.2f} mm^2"
)
