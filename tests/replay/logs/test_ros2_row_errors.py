"""The row checks' errors of the PointCloud2 and Image decoders, whole and to the byte: their texts are built
only on error (replay.logs.ros2_msgs._check_rows), from templates; a prefix with braces stays as it is."""

from __future__ import annotations

import pytest

from replay.errors import LogFormatError
from replay.logs import ros2_msgs as rm

WHERE = "topic /{w}, message 3"  # braces: the prefix is never a template


def _cloud(**over: object) -> rm.CloudMsg:
    kw: dict = dict(stamp_ns=0, frame_id="f", height=2, width=3, fields=rm.XYZRGBA_FIELDS, point_step=16,
                    row_step=48, data=bytes(96), is_dense=False)
    kw.update(over)
    return rm.decode_cloud(rm.encode_cloud(**kw), where=WHERE)


def _image(encoding: str, *, height: int, width: int, step: int, n: int) -> rm.ImageMsg:
    return rm.decode_image(rm.encode_image(stamp_ns=0, frame_id="c", height=height, width=width, encoding=encoding,
                                           step=step, data=bytes(n)), where=WHERE)


@pytest.mark.parametrize(
    ("decode", "msg", "text"),
    [
        (rm.cloud_to_arrays, _cloud(row_step=40),
         "PointCloud2 row_step 40 is smaller than width 3 x point_step 16"),
        (rm.cloud_to_arrays, _cloud(height=3),
         "PointCloud2 of 3x3 with row_step 48, point_step 16 needs 144 bytes of data but has 96"),
        (rm.cloud_to_arrays, _cloud(width=2**31 - 1, row_step=2**32 - 1, point_step=1, fields=rm.XYZ_FIELDS),
         "PointCloud2 of 2x2147483647 with row_step 4294967295, point_step 1 needs 6442450942 bytes of data but "
         "has 96"),
        (rm.image_to_rgb, _image("rgb8", height=5, width=7, step=20, n=200),
         "Image step 20 is smaller than width 7 x 3 bytes (rgb8)"),
        (rm.image_to_rgb, _image("bgra8", height=5, width=7, step=29, n=100),
         "Image 5x7 bgra8 with step 29 needs 144 bytes of data but has 100"),
        (rm.image_to_mask, _image("mono8", height=5, width=7, step=6, n=100),
         "Image step 6 is smaller than width 7 x 1 bytes (mono8)"),
        (rm.image_to_mask, _image(rm.PACKED_MASK_ENCODING, height=4, width=11, step=1, n=8),
         "Image step 1 is smaller than width 11 / 8 bytes, rounded up (2; mono1)"),
        (rm.image_to_mask, _image(rm.PACKED_MASK_ENCODING, height=4, width=11, step=2, n=7),
         "Image 4x11 mono1 with step 2 needs 8 bytes of data but has 7"),
    ],
)
def test_row_errors_whole(decode, msg, text: str) -> None:
    with pytest.raises(LogFormatError) as err:
        decode(msg, where=WHERE)
    assert str(err.value) == f"{WHERE}: {text}"


def test_the_cap_after_the_rows() -> None:
    """Rows that fit, a grid over the cap: check_grid's error, named by the decoder's kind."""
    with pytest.raises(LogFormatError) as err:
        rm.image_to_rgb(_image("mono8", height=5, width=7, step=7, n=35), where=WHERE, max_pixels=34)
    assert str(err.value) == (f"{WHERE}: Image of 5x7 = 35 pixels is more than the cap of 34 (max_pixels; raise "
                              "it with ZCUT_MAX_PIXELS)")
