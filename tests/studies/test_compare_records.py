"""A unit's images of a frame (``studies.compare_records.FrameImages``) read back as they were written: the
set pixels the part keeps, and the dense images a part written before held."""

from __future__ import annotations

import io

import numpy as np
import pytest

from studies.compare_records import FrameImages, FrameView


def _images(rng, h, w, density):
    def img(codes):
        out = np.zeros((h, w), np.uint8)
        on = rng.random((h, w)) < density
        out[on] = rng.choice(codes, size=int(on.sum()))
        return out

    return img([1, 2, 3]), img([1, 2, 3, 4]), img([1, 2, 3, 4, 5]), img([1, 2])


@pytest.mark.parametrize("h, w, density", [(30, 40, 0.05), (1, 50, 0.5), (20, 1, 1.0), (16, 16, 0.0), (60, 80, 0.9)])
@pytest.mark.parametrize("with_view", [False, True])
def test_images_read_back_as_written(rng, h, w, density, with_view):
    va, vb, diff, who = _images(rng, h, w, density)
    view = None
    if with_view:
        n = int(np.count_nonzero(diff))
        view = FrameView(b"\xff\xd8 not a real jpeg \xff\xd9", None, rng.random((n, 3)).astype(np.float32),
                         diff[diff > 0])
    back = FrameImages.from_bytes(FrameImages(va, vb, diff, who, view).to_bytes())
    for got, want in zip((back.verdict_a, back.verdict_b, back.diff, back.who), (va, vb, diff, who), strict=True):
        assert got.dtype == np.uint8 and np.array_equal(got, want)
    assert (back.view is None) == (view is None)
    if view is not None:
        assert back.view.jpeg == view.jpeg and back.view.image is None
        assert np.array_equal(back.view.points, view.points) and np.array_equal(back.view.point_ids, view.point_ids)


def test_a_part_written_with_dense_images_still_reads(rng):
    """A part of a comparison run before the images were kept as their set pixels (dense, deflated)."""
    va, vb, diff, who = _images(rng, 25, 35, 0.1)
    gray = rng.integers(0, 255, (25, 35), dtype=np.uint8)
    buf = io.BytesIO()
    np.savez_compressed(buf, verdict_a=va, verdict_b=vb, diff=diff, who=who, points=np.zeros((0, 3), np.float32),
                        point_ids=np.zeros(0, np.uint8), image=gray)
    back = FrameImages.from_bytes(buf.getvalue())
    for got, want in zip((back.verdict_a, back.verdict_b, back.diff, back.who), (va, vb, diff, who), strict=True):
        assert np.array_equal(got, want)
    assert back.view is not None and back.view.jpeg is None and np.array_equal(back.view.image, gray)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_images_made_at_the_regions_pixels_equal_the_whole_frame_images(seed):
    """The unit's images made at the scored regions' pixels alone (``frame_images_bytes``) are those of the
    whole-frame images (``diff_image``, ``frame_images``): the same bytes, the same view; with and without
    truth (its outliers also outside the scored pixels), regions of A and B that differ or are one array,
    invalid points, an RGB image or none."""
    from types import SimpleNamespace

    from studies.compare import diff_image, scored_union
    from studies.compare_outputs import frame_images, frame_images_bytes
    from studies.compare_records import SideFrame

    rng = np.random.default_rng(seed)
    h, w = 47, 61
    valid = rng.random((h, w)) > 0.1
    valid[10:30, 5:25] = False
    ra, rb = valid & (rng.random((h, w)) > 0.2), valid.copy()
    rb[:, : w // 3] = False
    for density in (0.0, 0.05, 0.5):
        sa = SideFrame({"zcut": rng.random((h, w)) < density}, valid, ra)
        sb = SideFrame({"zcut": rng.random((h, w)) < density, "sor": rng.random((h, w)) < 0.1}, valid, rb)
        lab = (rng.random((h, w)) < 0.2) & valid
        reviewed = valid & (rng.random((h, w)) > 0.3)
        xyz = rng.random((h, w, 3)).astype(np.float32)
        xyz[~valid] = np.nan
        rgb = rng.integers(0, 255, (h, w, 3), dtype=np.uint8)
        for truth in (None, (lab & reviewed, reviewed & (ra | rb)), (lab, reviewed & ra)):
            for pb in ("zcut", "sor"):
                for frame in (None, SimpleNamespace(xyz=xyz, rgb=rgb), SimpleNamespace(xyz=xyz, rgb=None)):
                    diff = diff_image(sa.preds["zcut"], sb.preds[pb], ra | rb, truth)
                    want = frame_images(sa, sb, diff, truth, "zcut", pb, frame).to_bytes()
                    got = frame_images_bytes(sa, sb, truth, "zcut", pb, frame)
                    assert got == want
                    assert frame_images_bytes(sa, sb, truth, "zcut", pb, frame, where=ra | rb) == want
        same = SideFrame(sb.preds, valid, ra)  # B judged A's zone: one region array (scored_union gives it back)
        assert scored_union(sa, same) is ra
        for truth in (None, (lab & reviewed, reviewed & ra)):
            diff = diff_image(sa.preds["zcut"], same.preds["zcut"], ra, truth)
            want = frame_images(sa, same, diff, truth, "zcut", "zcut", None).to_bytes()
            assert frame_images_bytes(sa, same, truth, "zcut", "zcut", None, where=scored_union(sa, same)) == want
