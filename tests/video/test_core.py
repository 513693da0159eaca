"""The video types (:mod:`anra_torch.video.core`): the truth a file records; clean frames follow the steps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from anra_torch.video import (
    Truth,
    crop,
    load_video,
    resample_uniform,
    save_npz,
)


def test_no_truth_without_its_keys_and_a_bad_effects_entry(tmp_path: Path) -> None:
    assert load_video(save_npz(tmp_path / "plain.npz", np.zeros((4, 3, 3)), dt=0.1, dx=0.1)).truth is None
    partial = load_video(save_npz(tmp_path / "a.npz", np.zeros((4, 3, 3)), dt=0.1, dx=0.1, a_true=0.2))
    assert partial.truth == Truth(a=0.2)
    bad = save_npz(tmp_path / "bad.npz", np.zeros((4, 3, 3)), dt=0.1, dx=0.1, effects="advection")
    with pytest.raises(ValueError, match=r"bad\.npz: effects must be a JSON list of effect records"):
        load_video(bad)


def test_clean_frames_follow_crop_and_resampling() -> None:
    from anra_torch.video import Video

    t = torch.tensor([0.0, 1.0, 3.0, 4.0], dtype=torch.float64)
    frames = torch.arange(4 * 3 * 5, dtype=torch.float64).reshape(4, 3, 5)
    video = Video(frames + 1, dt=1.0, dx=0.1, t=t, truth=Truth(a=0.1, clean=frames))
    done = crop(resample_uniform(video), (1, 0, 3, 2))
    torch.testing.assert_close(done.truth.clean, done.frames - 1)
    assert done.truth.clean.shape == (5, 2, 3)
