"""What the plain heat equation misses: diagnose a video with a hidden effect.

:func:`anra_torch.hidden_effect_video` simulates heat transfer with one effect the plain equation does not
have (here advection, drawn at random with its truth kept). :func:`anra_torch.diagnose_terms` balances the
candidate terms on the frames, keeps the significant ones (Wald tests against the measured noise) and
states their coefficients with standard errors. :func:`anra_torch.assess_gain` (or ``anra diagnose
VIDEO``) then forecasts held-out frames with the plain and the extended model: minutes on a shared CPU,
left out here.

    python examples/diagnose_simulated.py
"""

from anra_torch import diagnose_terms, hidden_effect_video
from anra_torch.effects import Sensor

video = hidden_effect_video("advection", seed=0, size=48, duration=1.5, sensor=Sensor(noise_sd=0.01))
print("hidden:", [effect.name for effect in video.effects], "a =", video.a, "mm^2/s")
diagnosis = diagnose_terms(video.frames, video.dt, video.dx)
print("named:", [effect["name"] for effect in diagnosis.effects], "a =", round(diagnosis.base, 4), "mm^2/s")
for name, value in diagnosis.coefficients.items():
    print(f"  {name} = {value:.4g} +- {diagnosis.std_errors.get(name, float('nan')):.2g}")
