"""``explained`` with its fits searching the zone without the pixels the straggler bound gave back to it
(:data:`replay.pipeline.explained.FITS_WITHOUT_PUT_BACK`, :func:`replay.pipeline.explained.fit_region`; docs/labelling.md,
"Tenth round").

A real ray-traced log (``write_raytraced_log``, zinc nuts at 200 × 320, the pile on the bin floor), its zone as the
pipeline makes it with the defaults and with ``[removal] straggler_bound = "off"`` (the oracle of the given-back
pixels). Off by default: the method as before, bit for bit.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import replay.pipeline.explained as pe
from replay.options import PipelineOptions
from replay.pipeline.stages import bin_zone

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def prepared(tmp_path_factory):
    from replay.synth.raytrace import write_raytraced_log

    log = write_raytraced_log(tmp_path_factory.mktemp("putback") / "rt.mcap", kind="zinc_nuts", frames=1, seed=9641,
                              size=(200, 320))
    session = PipelineOptions(methods="zcut,explained").open_session(log)
    frame, result = next(iter(session.results()))
    assert session.prepared is not None
    zone = bin_zone(frame, session.config, bin_model=session.prepared)
    off = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal,
                                                                          straggler_bound="off"))
    from zcut.prepared_model import prepare_bin_model

    zone_off = bin_zone(frame, off, bin_model=prepare_bin_model(session.prepared.model, registration=off.registration,
                                                                 removal=off.removal), located=zone.located)
    return session, frame, zone, zone_off, result


def _run(frame, zone, config, monkeypatch, on: bool):
    monkeypatch.setattr(pe, "FITS_WITHOUT_PUT_BACK", on)
    return pe.run_explained(frame, zone, config, judge_above_rim=True)


def test_the_fit_region_is_the_zone_without_what_the_bound_gave_back(prepared):
    session, frame, zone, zone_off, _ = prepared
    given_back = zone.zone & ~zone_off.zone
    assert given_back.sum() > 20 and not (zone_off.zone & ~zone.zone).any()
    np.testing.assert_array_equal(pe.fit_region(frame, zone, session.config), zone.zone & ~given_back)
    # with the bound off nothing is given back: the region is the zone
    off = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal,
                                                                          straggler_bound="off"))
    np.testing.assert_array_equal(pe.fit_region(frame, zone_off, off), zone_off.zone)


def test_the_fits_search_the_region_and_every_zone_pixel_is_judged(prepared, monkeypatch):
    session, frame, zone, _, result = prepared
    region = pe.fit_region(frame, zone, session.config)
    out, d, _ = _run(frame, zone, session.config, monkeypatch, True)
    assert d is not None and d.fits
    for f in (*d.fits, *d.vetted_out):  # found on the region's pixels only
        assert region.reshape(-1)[f.pixels].all()
    valid = np.isfinite(frame.xyz).all(axis=2)
    assert not np.isnan(d.dist_mm[zone.zone & valid]).any()  # every zone pixel judged, the given-back ones too
    assert not (out & ~zone.zone).any()
    given_back = zone.zone & ~region
    assert (d.surface[given_back] != -1).all()  # each has a nearest known surface
    # the default: the method's outliers as the pipeline gave them
    out0, d0, _ = _run(frame, zone, session.config, monkeypatch, False)
    assert d0 is not None
    np.testing.assert_array_equal(out0, np.asarray(result.outliers[pe.NAME], bool) & zone.zone)


def test_off_by_default_and_the_same_where_nothing_was_given_back(prepared, monkeypatch):
    session, frame, zone, zone_off, _ = prepared
    assert pe.FITS_WITHOUT_PUT_BACK is False
    off = dataclasses.replace(session.config, removal=dataclasses.replace(session.config.removal,
                                                                          straggler_bound="off"))
    a_out, a, _ = _run(frame, zone_off, off, monkeypatch, False)
    b_out, b, _ = _run(frame, zone_off, off, monkeypatch, True)
    assert a is not None and b is not None
    np.testing.assert_array_equal(a_out, b_out)
    np.testing.assert_array_equal(a.dist_mm, b.dist_mm)
    np.testing.assert_array_equal(a.surface, b.surface)
    np.testing.assert_array_equal(a.err_mm, b.err_mm)
    assert [f.pose.tolist() for f in a.fits] == [f.pose.tolist() for f in b.fits]
