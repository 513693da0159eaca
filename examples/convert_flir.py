"""Convert a FLIR research-camera file (.fff, .seq, .csq) to .npz, and read it back.

``anra convert`` reads any recording anra reads, chunk by chunk, and writes the frames as float32 degrees
Celsius with their times and the camera's metadata. The shared data hold one FFF frame (the container of
every frame of a .seq or .csq sequence); a .seq converts the same way, frame after frame.

    python examples/convert_flir.py [FILE]      # default ../shared/data/flir_fff/frame_000000.fff
"""

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from anra_torch.cli import main
from anra_torch.video import load_video

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "flir_fff" / "frame_000000.fff"

source = Path(sys.argv[1]) if len(sys.argv) > 1 else DATA
out = Path(tempfile.mkdtemp()) / "frames.npz"
if main(["convert", str(source), "-o", str(out)]) != 0:
    raise SystemExit(f"anra convert failed on {source}")
video = load_video(out, dt=0.04)  # a single frame has no frame period: give one
print(
    f"frames {tuple(video.frames.shape)}, {float(video.frames.min()):.2f}-{float(video.frames.max()):.2f} C"
)
with np.load(out) as stored:
    meta = json.loads(str(stored["meta"]))
print("camera metadata:", ", ".join(sorted(meta)[:8]), "...")
