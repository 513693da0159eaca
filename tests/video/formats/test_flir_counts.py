"""The raw counts of a FLIR frame (:mod:`anra_torch.video.formats.flir_counts`): uint16 in either byte order,
a truncated image, the byte order judged from the counts."""

from __future__ import annotations

import numpy as np
import pytest

from anra_torch.video.formats.flir_counts import decode_counts, swapped_rougher
from anra_torch.video.formats.flir_fff import RawImage, TruncatedFrame


def raw(order: str) -> RawImage:
    return RawImage(offset=0, length=24, width=4, height=3, encoding="uint16", order=order, swapped=False)


@pytest.mark.parametrize("order", ["<", ">"])
def test_uint16_counts_are_read_in_the_records_byte_order(order: str) -> None:
    counts = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    out = decode_counts(raw(order), counts.astype(order + "u2").tobytes())
    np.testing.assert_array_equal(out, counts)
    assert out.dtype == np.dtype("=u2")


def test_cut_off_counts_are_a_truncated_frame() -> None:
    with pytest.raises(TruncatedFrame, match="truncated: the raw counts at byte 0 are cut off"):
        decode_counts(raw("<"), bytes(10))


def test_counts_far_smoother_swapped_are_judged_swapped_and_a_flat_frame_is_not() -> None:
    scene = (15000 + np.arange(64).reshape(8, 8) % 7).astype(np.uint16)
    assert not swapped_rougher(scene)
    assert swapped_rougher(scene.byteswap())
    assert not swapped_rougher(np.full((4, 4), 15000, dtype=np.uint16))
    assert not swapped_rougher(scene[:, :1])
