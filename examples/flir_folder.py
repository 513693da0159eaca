"""Estimate the diffusivity of a FLIR recording: a folder of radiometric JPEGs, one per frame.

The laser run Nov19_2 of the shared data (a 808 nm laser on carbon-black silicone, a frame every ~5 s, the
laser off at 60 s). Temperatures come from the raw counts, times from each frame's capture time; the
uneven times are resampled onto a uniform step. The heating and the cooling are found from the data and the
source-free one, the cooling, is estimated. A FLIR file does not know its pixel size: 0.55 mm follows from
the camera's field of view at 10 cm. ``anra estimate FOLDER --dx 0.55`` does all of this and more (every
phase, the depth-aware fit, flags); this is the same measurement in a few lines of Python.

    python examples/flir_folder.py [FOLDER]      # default ../shared/data/laser_silicone/Nov19_2
"""

import sys
from pathlib import Path

from anra_torch import ANRAEstimator, load_video
from anra_torch.video import recording_phases

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "laser_silicone" / "Nov19_2"

folder = Path(sys.argv[1]) if len(sys.argv) > 1 else DATA
video = load_video(folder, dx=0.55, timestamps="resample")  # frames (T, H, W) in degC, dt in s, dx in mm
phases = recording_phases(video.frames, video.t)
for p in phases:
    print(f"{p.name:8s} frames {p.start:2d}-{p.stop:2d}  {p.t_start:5.1f}-{p.t_stop:5.1f} s")
cooling = next(p for p in phases if p.name == "cooling")
result = ANRAEstimator(strict=False)(video.frames[cooling.start : cooling.stop], video.dt, video.dx)
print(f"cooling: a = {float(result.diffusivity):.4f} +- {float(result.std_error):.4f} mm^2/s")
