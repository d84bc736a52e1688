"""Tests of :mod:`camcal.models.flat`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.special import eval_legendre

from camcal.errors import CamcalError
from camcal.models.flat import FlatModel, PlaneGeometry, dead_pixels, radial_gain
from tests.helpers import _aperture_series, _json_round_trip, _vignetting
from tests.oracles import correct_flat


@pytest.mark.formula
def test_dead_pixels_are_strictly_below_the_threshold_and_none_without_a_response_map():
    chans = ("R", "G1", "G2", "B")
    prnu = np.ones((4, 2, 3), np.float32)
    prnu[0, 0, 0], prnu[1, 1, 2], prnu[3, 0, 1] = 0.5, 0.49, 0.3
    fm = FlatModel(channels=chans, centre_px={c: (1.0, 1.0) for c in chans}, k={c: (0.0,) for c in chans},
                   model_2d=None, prnu=prnu, residual_rms={}, shape=(2, 3), cfa_pattern="RGGB")
    dead = dead_pixels(fm)
    assert dead.dtype == bool and dead.sum() == 2 and dead[1, 1, 2] and dead[3, 0, 1] and not dead[0, 0, 0]
    assert dead_pixels(fm, threshold=0.6).sum() == 3 and dead_pixels(fm, threshold=0.31).sum() == 1
    none = dead_pixels(replace(fm, prnu=None))
    assert none.shape == (4, 2, 3) and none.dtype == bool and not none.any()


@pytest.mark.formula
def test_plane_geometry_without_a_mosaic_is_the_identity_and_rmax_the_farthest_corner():
    """A linear-RAW (no CFA) frame: plane pixels are image pixels (scale 1, no offset), and the normalising
    radius is the distance to the farthest of the four corners (0 or W − 1, 0 or H − 1), for a centre near
    each side."""
    geom = PlaneGeometry.for_planes(("R", "G", "B"), (30, 40), None)
    assert geom.full_shape == (30, 40)
    fx, fy = geom.to_full("G", np.array([0.0, 7.5]), np.array([3.0, 29.0]))
    np.testing.assert_array_equal(fx, [0.0, 7.5])
    np.testing.assert_array_equal(fy, [3.0, 29.0])
    for cx, cy in ((37.5, 2.0), (1.5, 27.0), (20.0, 14.5)):
        far = max(np.hypot(x - cx, y - cy) for x in (0.0, 39.0) for y in (0.0, 29.0))
        assert geom.rmax_full("B", cx, cy) == pytest.approx(far, rel=1e-15)
    bayer = PlaneGeometry.for_planes(("R", "G1", "G2", "B"), (30, 40), "RGGB")
    assert bayer.full_shape == (60, 80) and bayer.to_full("B", 2.0, 3.0) == (5.0, 7.0)


@pytest.mark.formula
def test_flat_gains_are_float32_maps():
    """The gain maps are stored and applied as float32 (the correction divides float32 planes by them)."""
    chans = ("R", "G1", "G2", "B")
    prnu = np.full((4, 6, 8), 1.01, np.float32)
    fm = FlatModel(channels=chans, centre_px={c: (3.5, 2.5) for c in chans},
                   k={c: (-0.3, 0.05, 0.0, 0.0, 0.0) for c in chans}, model_2d=None, prnu=prnu, residual_rms={},
                   shape=(6, 8), cfa_pattern="RGGB")
    coef = [[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]]
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef for c in chans}, "scale": {c: 0.9 for c in chans}}
    for g in (fm.gain(), fm.gain(with_prnu=True), fm.radial_gain(), replace(fm, model_2d=m2).gain()):
        assert g.dtype == np.float32 and g.shape == (4, 6, 8)
    with pytest.raises(CamcalError, match="no PRNU map"):
        replace(fm, prnu=None).gain(with_prnu=True)


def _flat_models():
    """A radial Bayer model at f/5.6 with a PRNU map and a model of the same planes at f/11; a 2-D linear one."""
    from camcal.models.flat import Optics

    ch = ("R", "G1", "G2", "B")
    prnu = (1.0 + 0.001 * np.arange(4 * 3 * 5).reshape(4, 3, 5)).astype(np.float32)
    kw = {"channels": ch, "model_2d": None, "shape": (3, 5), "cfa_pattern": "RGGB"}
    f11 = FlatModel(centre_px={c: (2.0 + 0.1 * i, 1.0 - 0.05 * i) for i, c in enumerate(ch)},
                    k={c: (-0.2 - 0.01 * i, 0.01, 0.0, 0.0, 0.0) for i, c in enumerate(ch)}, prnu=None,
                    residual_rms={c: 0.002 for c in ch}, level_dn={c: 900.0 for c in ch}, info={"n_terms": 2},
                    optics=Optics(11.0, "folder flat/f11/", 35.0, "tag"), **kw)
    radial = FlatModel(centre_px={c: (2.25 - 0.125 * i, 1.5 + 0.25 * i) for i, c in enumerate(ch)},
                       k={c: (-0.4 + 0.02 * i, 0.05, -0.01, 0.002, 0.0) for i, c in enumerate(ch)}, prnu=prnu,
                       residual_rms={c: 0.001 * (i + 1) for i, c in enumerate(ch)},
                       level_dn={c: 1000.0 + i for i, c in enumerate(ch)},
                       prnu_rms={c: 0.004 + 0.001 * i for i, c in enumerate(ch)},
                       info={"n_terms": 2, "frames": ["a.dng", "b.dng"]}, optics=Optics(5.6, "tag", 35.0, "libraw"),
                       apertures=(f11,), **kw)
    coef = {c: [[1.0, 0.0, -0.1], [0.02 * i, 0.0, 0.0], [-0.08, 0.0, 0.0]] for i, c in enumerate("RGB")}
    two_d = FlatModel(channels=("R", "G", "B"), centre_px={c: (1.5, 1.0) for c in "RGB"},
                      k={c: (0.0,) * 5 for c in "RGB"},
                      model_2d={"kind": "legendre2d", "degree": 2, "coefficients": coef,
                                "scale": {c: 1.0 + 0.01 * i for i, c in enumerate("RGB")}},
                      prnu=None, residual_rms={c: 0.003 for c in "RGB"}, shape=(3, 4), cfa_pattern=None)
    return radial, f11, two_d


def _same_flat(a, b, prnu=True):
    assert (a.channels, a.shape, a.cfa_pattern, a.model_2d, a.optics) == (b.channels, b.shape, b.cfa_pattern,
                                                                        b.model_2d, b.optics)
    assert (a.centre_px, a.k, a.residual_rms, a.level_dn, a.prnu_rms, a.info) == (
        b.centre_px, b.k, b.residual_rms, b.level_dn, b.prnu_rms, b.info)
    if prnu:
        assert (a.prnu is None) == (b.prnu is None)
        if a.prnu is not None:
            assert a.prnu.dtype == np.float32
            np.testing.assert_array_equal(a.prnu, b.prnu)


@pytest.mark.formula
def test_flat_record_round_trip_keeps_every_field_and_the_other_apertures():
    """flat_to_parts -> JSON text for the record -> flat_from_parts gives back every field of a radial model with
    a PRNU map and a model at another f-number (which shares the PRNU map), and of a 2-D Legendre model; the gain
    of the model read back is the DNG radial sum 1 + k0 r² + k1 r⁴ + ... written out here."""
    from camcal.models.flat import flat_from_parts, flat_to_parts

    radial, f11, two_d = _flat_models()
    data, maps = flat_to_parts(radial)
    back = flat_from_parts(_json_round_trip(data), {n: np.asarray(m, float) for n, m in maps.items()}, "f.json")
    _same_flat(back, radial)
    assert len(back.apertures) == 1
    _same_flat(back.apertures[0], f11, prnu=False)
    np.testing.assert_array_equal(back.apertures[0].prnu, radial.prnu)
    assert back.apertures[0].apertures == ()
    # the gain of the R plane (offset (0, 0), 2 mosaic px per plane px) from the radial sum written out
    cx, cy = radial.centre_px["R"]
    yy, xx = np.mgrid[0:3, 0:5].astype(float)
    fx, fy = 2 * cx, 2 * cy
    rmax = max(np.hypot(x - fx, y - fy) for x in (0.0, 9.0) for y in (0.0, 5.0))
    r2 = ((2 * xx - fx) ** 2 + (2 * yy - fy) ** 2) / rmax**2
    g = 1 + sum(kk * r2 ** (i + 1) for i, kk in enumerate(radial.k["R"]))
    np.testing.assert_allclose(back.gain()[0], g, rtol=1e-6)  # float32 map

    # a record whose other model says it has a PRNU map: that model takes this model's all the same
    data2 = _json_round_trip(data)
    data2["apertures"][0]["has_prnu"] = True
    np.testing.assert_array_equal(flat_from_parts(data2, dict(maps)).apertures[0].prnu, radial.prnu)

    data, maps = flat_to_parts(two_d)
    back = flat_from_parts(_json_round_trip(data), dict(maps))
    _same_flat(back, two_d)
    assert back.apertures == () and back.prnu is None
    u = 2.0 * np.arange(4) / 3.0 - 1.0
    v = 2.0 * np.arange(3) / 2.0 - 1.0
    p2 = lambda t: 1.5 * t * t - 0.5  # noqa: E731 - Legendre P2
    gb = 1.01 * (1.0 - 0.1 * p2(v)[:, None] + 0.02 * u[None, :] - 0.08 * p2(u)[None, :])
    np.testing.assert_allclose(back.gain()[1], gb, rtol=1e-6)  # float32 map

    # a 2-D model with a 2-D model at another f-number: the other model's own coefficients come back
    from camcal.models.flat import Optics

    coef = {c: [[1.0, 0.0, -0.2], [0.01, 0.0, 0.0], [-0.05, 0.0, 0.0]] for c in "RGB"}
    other = replace(two_d, model_2d={**two_d.model_2d, "coefficients": coef}, optics=Optics(8.0, "tag", 35.0, "tag"))
    with_other = replace(two_d, optics=Optics(4.0, "tag", 35.0, "tag"), apertures=(other,))
    data, maps = flat_to_parts(with_other)
    back = flat_from_parts(_json_round_trip(data), dict(maps))
    assert back.apertures[0].model_2d == other.model_2d and back.apertures[0].optics == other.optics
    assert back.apertures[0].prnu is None


@pytest.mark.formula
def test_flat_model_summary_names_its_kind_normalisation_full_frame_centres_and_corner_gains():
    """The summary a profile and a report show: the kind of model, the normalisation in words, each plane's
    optical centre in mosaic pixels (RGGB: plane pixel (x, y) of R is mosaic (2x, 2y), of G1 (2x + 1, 2y), of G2
    (2x, 2y + 1), of B (2x + 1, 2y + 1)) and the smallest gain at the plane's four corners, from the radial sum
    1 + Σ k_i r^(2i+2) written out at the corners of the R plane."""
    radial, _, two_d = _flat_models()
    s = radial.summary()
    assert s["model"] == "radial" and two_d.summary()["model"] == "2d"
    assert s["normalisation"] == "gain = 1 at the optical centre (radiance refers to on-axis sensitivity)"
    offsets = {"R": (0, 0), "G1": (1, 0), "G2": (0, 1), "B": (1, 1)}
    for c, (ox, oy) in offsets.items():
        cx, cy = radial.centre_px[c]
        assert s["centre_full_px"][c] == [pytest.approx(2 * cx + ox), pytest.approx(2 * cy + oy)]
    cx, cy = radial.centre_px["R"]
    fx, fy = 2 * cx, 2 * cy
    rmax = max(np.hypot(x - fx, y - fy) for x in (0.0, 9.0) for y in (0.0, 5.0))
    corners = [((2 * x - fx) ** 2 + (2 * y - fy) ** 2) / rmax**2 for x in (0.0, 4.0) for y in (0.0, 2.0)]
    g = [1 + sum(kk * r2 ** (i + 1) for i, kk in enumerate(radial.k["R"])) for r2 in corners]
    assert s["corner_gain"]["R"] == pytest.approx(min(g), rel=1e-6)  # float32 map values


@pytest.mark.formula
def test_flat_record_optional_fields_take_their_defaults():
    """A record with only the required fields: no CFA, no levels, PRNU RMS, info or optics, radial."""
    from camcal.models.flat import Optics, flat_from_parts

    m = flat_from_parts({"channels": ["R", "G", "B"], "shape": ["2", 3.0], "centre_px": {c: ["1", 0.5] for c in "RGB"},
                         "k": {c: ["-0.1", 0] for c in "RGB"}, "residual_rms": {c: "0.01" for c in "RGB"},
                         "level_dn": None, "has_prnu": False}, {})
    assert m.channels == ("R", "G", "B") and m.shape == (2, 3) and m.cfa_pattern is None and m.model_2d is None
    assert m.centre_px == {c: (1.0, 0.5) for c in "RGB"} and m.k == {c: (-0.1, 0.0) for c in "RGB"}
    assert m.residual_rms == {c: 0.01 for c in "RGB"} and m.prnu is None and m.apertures == ()
    assert m.level_dn == {} and m.prnu_rms == {} and m.info == {} and m.optics == Optics()


def _legendre_2x2(a, b, big=0.5e308):
    """A 2-D model (linear planes R, G, B on 3 x 4) g = big (1 + a u)(1 + b v): it overflows to inf at the corner
    (u, v) = (a, b) only (2e308 there; 0 or big elsewhere on the corners)."""
    return {"kind": "legendre2d", "degree": 1, "coefficients": {c: [[big, b * big], [a * big, a * b * big]]
                                                               for c in "RGB"}, "scale": {c: 1.0 for c in "RGB"}}


def _flat_record(model_2d=None, k=(-0.3, 0.0), centre=(1.5, 1.0)):
    return {"channels": ["R", "G", "B"], "shape": [3, 4], "centre_px": {c: list(centre) for c in "RGB"},
            "k": {c: list(k) for c in "RGB"}, "residual_rms": {c: 0.01 for c in "RGB"}, "model_2d": model_2d}


@pytest.mark.formula
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # the overflow the probe must see
@pytest.mark.parametrize(("a", "b"), [(-1, -1), (1, -1), (-1, 1), (1, 1)])
def test_flat_record_is_probed_at_each_of_the_four_plane_corners(a, b):
    """A model that is not finite at one plane corner is refused, whichever corner; a model finite at the four
    corners (g = 1.7e308 u, or v, which would overflow beyond them) is accepted."""
    from camcal.models.flat import flat_from_parts

    with pytest.raises(CamcalError) as e:
        flat_from_parts(_flat_record(_legendre_2x2(a, b)), {}, "f.json")
    assert str(e.value) == ("f.json: not a valid camcal flat file (ValueError: the vignetting model of R is not "
                            "finite at the corners)")
    edge = {"kind": "legendre2d", "degree": 1, "scale": {c: 1.0 for c in "RGB"},
            "coefficients": {c: [[0.0, 0.0], [1.7e308, 0.0]] if a > 0 else [[0.0, 1.7e308], [0.0, 0.0]]
                             for c in "RGB"}}
    assert flat_from_parts(_flat_record(edge), {}).kind == "2d"
    # radial: centre on the (a, b) corner's opposite, huge k: r² = 1 (overflow) only at the (a, b) corner
    centre = (0.0 if a > 0 else 3.0, 0.0 if b > 0 else 2.0)
    with pytest.raises(CamcalError, match="the vignetting model of R is not finite at the corners"):
        flat_from_parts(_flat_record(k=(1e308, 1e308), centre=centre), {})


@pytest.mark.formula
@pytest.mark.parametrize(("change", "maps", "says"), [
    ({"has_prnu": True}, {f"prnu.{c}": np.ones((3, 3)) for c in "RGB"},
     "(ValueError: PRNU maps do not match the recorded shape)"),
    ({"has_prnu": True}, {f"prnu.{c}": np.ones((2, 4)) for c in "RGB"},
     "(ValueError: PRNU maps do not match the recorded shape)"),
    ({"has_prnu": True}, {"prnu.R": np.ones((3, 4))}, "(KeyError: 'prnu.G')"),
    ({"apertures": [{**_flat_record(), "shape": [3, 5]}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"apertures": [{**_flat_record(), "shape": [4, 4]}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"apertures": [{**_flat_record(), "channels": ["R", "G", "X"], "centre_px": {c: [1, 1] for c in "RGX"},
                     "k": {c: [0] for c in "RGX"}, "residual_rms": {c: 0 for c in "RGX"}}]}, {},
     "(ValueError: a model of another f-number has other planes or another shape)"),
    ({"channels": ["R", "G", "X"]}, {}, "(KeyError: 'X')"),
    ({"shape": [3]}, {}, "(IndexError: "),
    ({"k": {c: [float("nan")] for c in "RGB"}}, {}, "(ValueError: the vignetting model of R is not finite"),
    ({"model_2d": {"kind": "legendre2d", "coefficients": {c: [[1.0]] for c in "RGB"}}}, {}, "(KeyError: 'scale')"),
    ({"centre_px": None}, {}, "(TypeError: "),
])
def test_flat_record_refusals_name_the_file_and_the_fault(change, maps, says):
    """A record whose PRNU maps, other f-number models or fields do not fit: one line naming the file and the
    exception."""
    from camcal.models.flat import flat_from_parts

    with pytest.raises(CamcalError) as e:
        flat_from_parts({**_flat_record(), **change}, maps, "cam/flat.json")
    assert str(e.value).startswith(f"cam/flat.json: not a valid camcal flat file {says}")


@pytest.mark.formula
def test_flat_record_with_a_malformed_model_of_another_f_number_names_the_file():
    """A record whose model of another f-number lacks a field is refused naming the file, like the record itself."""
    from camcal.models.flat import flat_from_parts

    other = {k: v for k, v in _flat_record().items() if k != "k"}
    with pytest.raises(CamcalError) as e:
        flat_from_parts({**_flat_record(), "apertures": [other]}, {}, "cam/flat.json")
    assert str(e.value) == "cam/flat.json: not a valid camcal flat file (KeyError: 'k')"


def _corners(g):
    return np.stack([g[:, 0, 0], g[:, 0, -1], g[:, -1, 0], g[:, -1, -1]], axis=1)


@pytest.mark.formula
def test_flat_choice_interpolates_ln_gain_in_inverse_f_number_squared_between_the_nearest_models():
    """A photo at f/4 between flats at f/2.8 and f/5.6 (and f/11): weights of ln g from 1/N² written out, the gain
    exp(w ln g_2.8 + (1 - w) ln g_5.6) pixel by pixel (times the shared PRNU when asked), the corner uncertainty
    as the largest |ratio - 1| at the corners against interpolating in ln N instead, the warning, description and
    record; float32 maps, so rtol 1e-6."""
    from camcal.models.flat import choose_flat

    primary, m28, m11, gains, prnu = _aperture_series()
    assert primary.models() == (m28, primary, m11) and primary.f_numbers() == [2.8, 5.6, 11.0]
    c = choose_flat(primary, 4.0, 35.0)
    w = (1 / 16 - 1 / 5.6**2) / (1 / 2.8**2 - 1 / 5.6**2)
    assert c.how == "interpolated" and c.mismatch is True
    assert [m for m, _ in c.parts] == [m28, primary]
    assert [x for _, x in c.parts] == [pytest.approx(w, rel=1e-12), pytest.approx(1 - w, rel=1e-12)]
    assert c.photo_f_number == 4.0 and c.photo_focal_length_mm == 35.0
    g = np.exp(w * np.log(gains[2.8]) + (1 - w) * np.log(gains[5.6]))
    assert c.gain().dtype == np.float32 and c.gain(with_prnu=True).dtype == np.float32
    np.testing.assert_allclose(c.gain(), g, rtol=1e-6)
    np.testing.assert_allclose(c.gain(with_prnu=True), g * prnu, rtol=1e-6)
    wl = np.log(5.6 / 4.0) / np.log(5.6 / 2.8)
    la, lb = np.log(_corners(gains[2.8])), np.log(_corners(gains[5.6]))
    diff = np.max(np.abs(np.exp(w * la + (1 - w) * lb) / np.exp(wl * la + (1 - wl) * lb) - 1))
    assert c.corner_difference_rel == pytest.approx(diff, rel=1e-9)
    assert c.warning == ("f/4 photo between the flats' f/2.8, 35 mm and f/5.6, 35 mm: vignetting interpolated (ln g "
                         f"linear in 1/N²); corners uncertain by up to ±{100 * diff:.2g} % (the difference from "
                         "interpolating in ln N)")
    assert c.describe() == "f/2.8, 35 mm and f/5.6, 35 mm (ln g interpolated linearly in 1/N²)"
    assert c.key == ((2.8, round(w, 9)), (5.6, round(1 - w, 9)))
    assert c.record(primary) == {
        "photo_f_number": 4.0, "photo_focal_length_mm": 35.0, "flat_f_numbers": [2.8, 5.6, 11.0],
        "flat_focal_length_mm": [35.0, 35.0, 35.0], "vignetting_model": c.describe(), "how": "interpolated",
        "weights": [[2.8, c.parts[0][1]], [5.6, c.parts[1][1]]], "corner_difference_rel": c.corner_difference_rel,
        "warning": c.warning, "mismatch": True,
        "rule": "ln g linear in 1/N² between measured f-numbers of models of the same form; outside: the nearest "
                "(docs/flat.md)"}
    # between f/5.6 and f/11 the pair is (5.6, 11), not the outermost models
    c8 = choose_flat(primary, 8.0, None)
    w8 = (1 / 64 - 1 / 121) / (1 / 5.6**2 - 1 / 121)
    assert [m for m, _ in c8.parts] == [primary, m11] and c8.parts[0][1] == pytest.approx(w8, rel=1e-12)
    np.testing.assert_allclose(c8.gain(), np.exp(w8 * np.log(gains[5.6]) + (1 - w8) * np.log(gains[11.0])),
                               rtol=1e-6)
    # the warning at f/10, between f/5.6 and f/11 (its percentage rounded to two digits: 1.2 %)
    w10, wl10 = (1 / 100 - 1 / 121) / (1 / 5.6**2 - 1 / 121), np.log(11 / 10) / np.log(11 / 5.6)
    la, lb = np.log(_corners(gains[5.6])), np.log(_corners(gains[11.0]))
    d10 = np.max(np.abs(np.exp((w10 - wl10) * (la - lb)) - 1))
    assert choose_flat(primary, 10.0, None).warning == (
        "f/10 photo between the flats' f/5.6, 35 mm and f/11, 35 mm: vignetting interpolated (ln g linear in "
        f"1/N²); corners uncertain by up to ±{100 * d10:.2g} % (the difference from interpolating in ln N)")
    assert f"{100 * d10:.2g}" == "1.2"
    # without a PRNU map an interpolated gain with PRNU is refused
    bare = [replace(m, prnu=None) for m in (m28, primary)]
    c0 = replace(c, parts=((bare[0], w), (bare[1], 1 - w)))
    np.testing.assert_allclose(c0.gain(), g, rtol=1e-6)
    with pytest.raises(CamcalError) as e:
        c0.gain(with_prnu=True)
    assert str(e.value) == "this flat model has no PRNU map (fitted without it)"


@pytest.mark.formula
def test_flat_choice_at_a_measured_f_number_and_outside_the_measured_range():
    """At a measured f-number (within 3 %: 2.83 is f/2.8) the model as it is, no warning; beyond the range the
    nearest model in 1/N², its corners' change extrapolated linearly in 1/N² from the next model written out."""
    from camcal.models.flat import choose_flat

    primary, m28, m11, gains, prnu = _aperture_series()
    for n, m in ((2.83, m28), (5.6, primary), (10.8, m11)):
        c = choose_flat(primary, n, 35.0)
        assert (c.how, c.parts, c.corner_difference_rel, c.mismatch, c.warning) == (
            "measured", ((m, 1.0),), None, False, None)
        np.testing.assert_allclose(c.gain(), gains[m.optics.f_number], rtol=1e-6)
        np.testing.assert_allclose(c.gain(with_prnu=True), gains[m.optics.f_number] * prnu, rtol=1e-6)
        assert c.describe() == f"{m.optics.label()} (measured at the photo's f-number)"
    for n, near, other in ((16.0, 11.0, 5.6), (2.0, 2.8, 5.6)):
        c = choose_flat(primary, n, 35.0)
        assert c.how == "nearest" and c.mismatch is True and c.parts[0][0].optics.f_number == near
        assert c.parts[0][1] == 1.0 and c.describe() == f"f/{near:g}, 35 mm (the nearest measured f-number)"
        ln, lo = np.log(_corners(gains[near])), np.log(_corners(gains[other]))
        ext = ln + (ln - lo) / (1 / near**2 - 1 / other**2) * (1 / n**2 - 1 / near**2)
        diff = np.max(np.abs(np.exp(ext - ln) - 1))
        assert c.corner_difference_rel == pytest.approx(diff, rel=1e-9)
        assert c.warning == (f"f/{n:g} photo, outside the flats' f/2.8, 35 mm – f/11, 35 mm: the f/{near:g}, 35 mm "
                             f"vignetting model is used; the corners may differ by about {100 * diff:.2g} %, "
                             f"extrapolating the change from f/{other:g}, 35 mm to f/{near:g}, 35 mm")


@pytest.mark.formula
def test_flat_choice_with_one_model_of_its_form_bounds_stopping_down_only():
    """Flats of one f-number: stopping down over-corrects the corners by at most 1/g_corner - 1; opening up has
    no bound. A pair of models of different forms is not interpolated: the nearest in 1/N² is used alone."""
    from camcal.models.flat import Optics, choose_flat

    primary, m28, m11, gains, _ = _aperture_series()
    only = replace(primary, apertures=())
    g_corner = float(np.min(_corners(gains[5.6])))
    c = choose_flat(only, 8.0, 35.0)
    assert (c.how, c.parts, c.mismatch) == ("nearest", ((only, 1.0),), True)
    assert c.corner_difference_rel == pytest.approx(1 / g_corner - 1, rel=1e-9)
    assert c.warning == (f"f/8 photo, flats at f/5.6, 35 mm only: the f/5.6, 35 mm vignetting model is used; the "
                         f"corners may differ by up to +{100 * (1 / g_corner - 1):.3g} % (stopping down reduces the "
                         f"flats' corner falloff of {100 * (1 - g_corner):.2g} %, so the corners are over-corrected "
                         "by at most 1/g - 1)")
    c = choose_flat(only, 4.0, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("nearest", ((only, 1.0),), None, True)
    assert c.warning == (f"f/4 photo, flats at f/5.6, 35 mm only: the f/5.6, 35 mm vignetting model is used; the "
                         f"corners may differ by an amount one flat cannot bound (a wider aperture vignettes more "
                         f"than the flats' {100 * (1 - g_corner):.2g} % corner falloff: the corners are "
                         "under-corrected, by tens of percent between f/2.8 and f/8 on real lenses)")
    # a model whose smallest corner gain is 1 - 0.3 + 0.056 = 0.756 (r² = 1 at the farthest corner): its
    # falloff, 24.4 %, in each message that gives it
    odd = replace(only, k={c: (-0.3, 0.056, 0.0, 0.0, 0.0) for c in "RG"})
    assert choose_flat(odd, 8.0, 35.0).warning.endswith(
        f"up to +{100 / 0.756 - 100:.3g} % (stopping down reduces the flats' corner falloff of 24 %, so the corners "
        "are over-corrected by at most 1/g - 1)")
    assert "more than the flats' 24 % corner falloff:" in choose_flat(odd, 4.0, 35.0).warning
    c = choose_flat(replace(odd, optics=Optics(5.6, "tag", 100.0, "tag")), 5.6, 99.0)
    assert c.corner_difference_rel == pytest.approx(0.244, rel=1e-6)  # float32 corner values
    assert c.warning.endswith("the corners may differ by as much as the flats' corner falloff, 24 %")
    # f/8 between f/5.6 and an f/11 model of three radial terms: not interpolated; f/11 is nearer in 1/N²
    three = replace(m11, info={"n_terms": 3})
    pair = replace(primary, apertures=(three,))
    g11 = float(np.min(_corners(gains[11.0])))
    c = choose_flat(pair, 8.0, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("nearest", ((three, 1.0),), None, True)
    assert c.warning.startswith("f/8 photo, outside the flats' f/5.6, 35 mm – f/11, 35 mm: the f/11, 35 mm "
                                f"vignetting model is used; the corners may differ by an amount one flat cannot "
                                f"bound (a wider aperture vignettes more than the flats' {100 * (1 - g11):.2g} %")
    # f/7 is nearer f/5.6 in 1/N² (1/49 - 1/121 > 1/31.36 - 1/49): f/5.6, stopped down
    c = choose_flat(pair, 7.0, 35.0)
    assert c.parts == ((pair, 1.0),) and c.corner_difference_rel == pytest.approx(1 / g_corner - 1, rel=1e-9)


@pytest.mark.formula
def test_flat_choice_unknown_f_numbers_and_another_focal_length():
    """An unknown f-number (the photo's or the flats') leaves the primary model unchecked, with a warning naming
    what to record; a focal length off by more than 1 % warns that the corners may differ by the flats' corner
    falloff 1 - min g (or the interpolation's uncertainty, if larger)."""
    from camcal.models.flat import Optics, choose_flat

    primary, m28, m11, gains, _ = _aperture_series()
    c = choose_flat(primary, None, 35.0)
    assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("unchecked", ((primary, 1.0),), None, True)
    assert c.warning == ("the photo's f-number is unknown: the vignetting model (flats at f/2.8, 35 mm, f/5.6, 35 mm, "
                         "f/11, 35 mm) is not checked")
    assert c.describe() == "f/5.6, 35 mm (f-number not checked)"
    unknown = replace(primary, optics=Optics(None, None, 35.0, "tag"), apertures=())
    for n, txt in ((8.0, "f/8"), (None, "f/?")):
        c = choose_flat(unknown, n, 35.0)
        assert (c.how, c.parts, c.corner_difference_rel, c.mismatch) == ("unchecked", ((unknown, 1.0),), None, True)
        assert c.warning == (f"the flats' f-number is unknown: the vignetting of this {txt} photo is not checked "
                             "(record f_number in the flats' frames.csv or session.toml)")
    assert unknown.optics.label() == "f/?, 35 mm" and Optics(8.0).label() == "f/8"
    # a model of unknown f-number among the apertures sorts last and is never chosen
    anon = replace(m11, optics=Optics(None, None, 35.0, "tag"))
    mixed = replace(primary, apertures=(anon, m28))
    assert mixed.models() == (m28, mixed, anon) and mixed.f_numbers() == [2.8, 5.6, None]
    assert choose_flat(mixed, 16.0, 35.0).parts[0][0] is mixed
    # focal length: 100 mm flats, a photo at 101 mm is the same setting (1 % of the shorter), 99 mm is not
    g_corner = float(np.min(_corners(gains[5.6])))
    at100 = replace(primary, optics=Optics(5.6, "tag", 100.0, "tag"), apertures=())
    assert choose_flat(at100, 5.6, 101.0).warning is None and choose_flat(at100, 5.6, 101.0).mismatch is False
    assert choose_flat(at100, 5.6, None).warning is None
    c = choose_flat(at100, 5.6, 99.0)
    assert c.mismatch is True and c.corner_difference_rel == pytest.approx(1 - g_corner, rel=1e-6)
    assert c.warning == ("focal length 99 mm, the flats' 100 mm: vignetting changes with the focal length, the "
                         f"corners may differ by as much as the flats' corner falloff, {100 * (1 - g_corner):.2g} %")
    # interpolated at another focal length: the larger of the interpolation's uncertainty and the falloff of
    # either model; the two notes joined by "; "
    c = choose_flat(primary, 4.0, 50.0)
    falloff = 1 - float(np.min(_corners(gains[2.8])))
    assert c.corner_difference_rel == pytest.approx(falloff, rel=1e-6)
    first = choose_flat(primary, 4.0, 35.0).warning
    assert c.warning == (f"{first}; focal length 50 mm, the flats' 35 mm: vignetting changes with the focal "
                         "length, the corners may differ by as much as the flats' corner falloff, "
                         f"{100 * falloff:.2g} %")
    # a model without a focal length is not checked against the photo's
    nofocal = replace(at100, optics=Optics(5.6, "tag", None, None))
    assert choose_flat(nofocal, 5.6, 50.0).warning is None


@pytest.mark.formula
def test_same_f_number_within_three_percent_of_the_smaller_and_same_form():
    """f-numbers within 3 % of the smaller are one (103 vs 100: exactly 3 %; 97 vs 100: 3.09 %); None is never
    the same. Models of the same kind, planes, shape, CFA and number of terms (radial) or degree (2-D) may be
    interpolated; any difference refuses."""
    from camcal.models.flat import same_f_number, same_form

    assert same_f_number(100.0, 103.0) and same_f_number(103.0, 100.0)
    assert not same_f_number(100.0, 97.0) and not same_f_number(97.0, 100.0)
    assert not same_f_number(None, 8.0) and not same_f_number(8.0, None) and not same_f_number(None, None)
    primary, m28, *_ = _aperture_series()
    _, _, two_d = _flat_models()
    assert same_form(primary, m28)
    assert not same_form(primary, replace(m28, info={"n_terms": 3}))
    assert not same_form(primary, replace(m28, info={}))
    assert not same_form(primary, replace(m28, channels=("G", "R")))
    assert not same_form(primary, replace(m28, shape=(3, 5)))
    assert not same_form(primary, replace(m28, cfa_pattern="RGGB"))
    assert not same_form(primary, replace(m28, model_2d=two_d.model_2d))
    assert same_form(two_d, replace(two_d, info={"n_terms": 7}))
    assert not same_form(two_d, replace(two_d, model_2d={**two_d.model_2d, "degree": 3}))
    assert not same_form(two_d, replace(two_d, model_2d={k: v for k, v in two_d.model_2d.items() if k != "degree"}))


@pytest.mark.formula
def test_flat_model_replace_keeps_the_evaluated_gain_only_while_the_model_is_unchanged():
    """A model holding its gain keeps it through a change of provenance or optics; a change of coefficients,
    centres, planes or shape evaluates the new model (the DNG sum written out)."""
    from camcal.models.flat import Optics

    primary, _, _, gains, _ = _aperture_series()
    held = np.full((2, 3, 4), 0.5, np.float32)
    m = primary.with_gain(held)
    kept = m.replace(info={"n_terms": 2, "note": "x"}, optics=Optics(8.0))
    np.testing.assert_array_equal(kept.gain(), held)
    assert kept.info["note"] == "x" and kept.optics.f_number == 8.0
    np.testing.assert_allclose(primary.replace(info={}).gain(), gains[5.6], rtol=1e-6)
    k = {"R": (-0.2, 0.0, 0.0, 0.0, 0.0), "G": (-0.1, 0.0, 0.0, 0.0, 0.0)}
    changed = m.replace(k=k, info={})
    np.testing.assert_allclose(changed.gain(), np.stack([_vignetting(k[c][:2], primary.centre_px[c], (3, 4))
                                                         for c in "RG"]), rtol=1e-6)


# A Bayer RGGB sensor of 60 x 80 mosaic pixels (planes 30 x 40), the optical centre off the middle.
FLAT_SHAPE = (30, 40)


FLAT_OFFSETS = {"R": (0, 0), "G1": (0, 1), "G2": (1, 0), "B": (1, 1)}  # (row, column) in the 2x2 cell, RGGB


def _dng_radial_gain(channel, cx, cy, k, xx, yy):
    """DNG FixVignetteRadial written out: r from the optical centre in mosaic pixels, normalised by the distance
    to the farthest corner of the 80 x 60 image; g = 1 + k0 r² + k1 r⁴ + k2 r⁶ + k3 r⁸ + k4 r¹⁰."""
    oy, ox = FLAT_OFFSETS[channel]
    fx, fy = 2 * xx + ox, 2 * yy + oy
    fcx, fcy = 2 * cx + ox, 2 * cy + oy
    rmax = max(np.hypot(cxn - fcx, cyn - fcy) for cxn in (0.0, 79.0) for cyn in (0.0, 59.0))
    r2 = ((fx - fcx) ** 2 + (fy - fcy) ** 2) / rmax**2
    return np.polynomial.polynomial.polyval(r2, [1.0, *k])


def _flat_model(k, centre, model_2d=None, prnu=None):
    chans = ("R", "G1", "G2", "B")
    return FlatModel(channels=chans, centre_px={c: centre for c in chans}, k={c: k for c in chans},
                     model_2d=model_2d, prnu=prnu, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")


@pytest.mark.formula
def test_radial_flat_gain_off_centre_is_the_dng_polynomial():
    """Every plane's gain against the DNG polynomial written out, with five non-zero k and the centre at plane
    pixel (14.3, 9.6) (off the middle, so the farthest corner and each plane's offset matter)."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    fm = _flat_model(k, (14.3, 9.6))
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = fm.gain()
    for i, c in enumerate(fm.channels):
        np.testing.assert_allclose(g[i], _dng_radial_gain(c, 14.3, 9.6, k, xx, yy), rtol=2e-7)  # float32 output
        corners = [_dng_radial_gain(c, 14.3, 9.6, k, x, y) for x in (0.0, 39.0) for y in (0.0, 29.0)]
        assert fm.corner_gain()[c] == pytest.approx(min(corners), rel=2e-7)
    assert fm.centre_full_px()["G2"] == pytest.approx((28.6, 20.2))


@pytest.mark.formula
def test_flat_gain_with_prnu_multiplies_and_dead_pixels_are_below_half():
    prnu = np.full((4, *FLAT_SHAPE), 1.02, np.float32)
    prnu[2, 3, 4] = 0.3
    fm = _flat_model((-0.3, 0.0, 0.0, 0.0, 0.0), (20.0, 15.0), prnu=prnu)
    np.testing.assert_allclose(fm.gain(with_prnu=True), fm.gain() * prnu, rtol=1e-7)
    dead = dead_pixels(fm)
    assert dead.sum() == 1 and dead[2, 3, 4]
    assert dead_pixels(fm, threshold=1.03).all()


@pytest.mark.formula
def test_2d_flat_gain_is_the_legendre_series_across_the_full_image():
    """g(u, v) = s Σ c_ij P_i(u) P_j(v), u = 2X/(W−1) − 1 and v = 2Y/(H−1) − 1 on full-resolution pixel centres
    (X, Y), with the Legendre polynomials from scipy.special, the scale s = 0.9 and a non-symmetric c."""
    coef = np.array([[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]])
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef.tolist() for c in FLAT_OFFSETS},
          "scale": {c: 0.9 for c in FLAT_OFFSETS}}
    fm = _flat_model((0.0,) * 5, (20.0, 15.0), model_2d=m2)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = fm.gain()
    for i, c in enumerate(fm.channels):
        oy, ox = FLAT_OFFSETS[c]
        u, v = 2 * (2 * xx + ox) / 79.0 - 1, 2 * (2 * yy + oy) / 59.0 - 1
        expect = 0.9 * sum(coef[a, b] * eval_legendre(a, u) * eval_legendre(b, v) for a in range(3) for b in range(3))
        np.testing.assert_allclose(g[i], expect, rtol=2e-6, atol=1e-7)


@pytest.mark.formula
def test_2d_flat_corner_values_are_the_legendre_series_at_each_planes_corners():
    """``corner_values`` evaluates a 2-D model at the four corners of each plane only (no full map): the Legendre
    series written out at the corner pixel centres (X, Y) of each plane's offset in the 80 x 60 mosaic, with a
    non-symmetric c (x and y not interchangeable) and a different scale per plane (planes not interchangeable).
    The corner gain is the smallest of the four, as float32 values."""
    coef = np.array([[1.0, 0.05, -0.1], [0.08, -0.03, 0.0], [-0.2, 0.0, 0.0]])
    scale = {"R": 0.9, "G1": 0.95, "G2": 0.85, "B": 0.8}
    m2 = {"kind": "legendre2d", "degree": 2, "coefficients": {c: coef.tolist() for c in FLAT_OFFSETS},
          "scale": scale}
    fm = _flat_model((0.0,) * 5, (20.0, 15.0), model_2d=m2)
    got = fm.corner_values()
    assert got.shape == (4, 4)
    for i, c in enumerate(fm.channels):
        oy, ox = FLAT_OFFSETS[c]
        xx, yy = np.array([0.0, 39.0, 0.0, 39.0]), np.array([0.0, 0.0, 29.0, 29.0])  # corners in corner_values' order
        u, v = 2 * (2 * xx + ox) / 79.0 - 1, 2 * (2 * yy + oy) / 59.0 - 1
        expect = scale[c] * sum(coef[a, b] * eval_legendre(a, u) * eval_legendre(b, v)
                                for a in range(3) for b in range(3))
        np.testing.assert_allclose(got[i], expect, rtol=1e-12)
        assert fm.corner_gain()[c] == float(np.float32(expect).min())


@pytest.mark.formula
def test_a_held_flat_gain_given_in_float64_is_kept_in_float32():
    """A calibration may pass ``with_gain`` a float64 map; the model holds and returns float32 (the type of every
    evaluated gain and of the profile's maps), with the values rounded to float32."""
    fm = _flat_model((-0.3, 0.0, 0.0, 0.0, 0.0), (20.0, 15.0))
    g64 = np.full((4, *FLAT_SHAPE), 0.1, np.float64)
    held = fm.with_gain(g64).gain()
    assert held.dtype == np.float32 and np.all(held == np.float32(0.1))


@pytest.mark.formula
def test_correct_flat_divides_by_the_gain():
    fm = _flat_model((-0.3, 0.05, 0.0, 0.0, 0.0), (10.0, 20.0))
    planes = np.full((4, *FLAT_SHAPE), 500.0, np.float32)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = np.stack([_dng_radial_gain(c, 10.0, 20.0, (-0.3, 0.05, 0.0, 0.0, 0.0), xx, yy) for c in fm.channels])
    np.testing.assert_allclose(correct_flat(planes * g, fm), planes, rtol=1e-5)


@pytest.mark.formula
def test_flat_corner_gain_is_the_smallest_of_the_four_corners_of_each_plane():
    """Each plane's optical centre near a different corner, so that each plane's smallest corner gain is at a
    different corner (the one farthest from its centre): the four corners of every plane against the DNG
    polynomial written out."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    centres = {"R": (33.0, 24.0), "G1": (6.0, 25.0), "G2": (34.0, 4.0), "B": (5.0, 5.0)}
    fm = FlatModel(channels=("R", "G1", "G2", "B"), centre_px=centres, k={c: k for c in centres}, model_2d=None,
                   prnu=None, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")
    got = fm.corner_gain()
    for c, (cx, cy) in centres.items():
        corners = {(x, y): float(_dng_radial_gain(c, cx, cy, k, x, y)) for x in (0.0, 39.0) for y in (0.0, 29.0)}
        assert got[c] == pytest.approx(min(corners.values()), rel=2e-7)  # float32 gains
    farthest = {c: min(corners, key=corners.get) for c, corners in
                ((c, {(x, y): float(_dng_radial_gain(c, *centres[c], k, x, y)) for x in (0.0, 39.0)
                      for y in (0.0, 29.0)}) for c in centres)}
    assert sorted(farthest.values()) == [(0.0, 0.0), (0.0, 29.0), (39.0, 0.0), (39.0, 29.0)]


@pytest.mark.formula
def test_flat_model_returns_the_gain_it_holds_and_its_corner_gains_are_the_float32_maps():
    """A model holding a gain (``with_gain``, as a calibration's fit passes it on) returns that array, read-only,
    not the model evaluated again: a held gain of 0.5 everywhere (the DNG polynomial gives 1 at the centre) comes
    back as 0.5. The corner gains are the float32 values of the map :meth:`gain` evaluates (exactly, not to
    float32 rounding)."""
    k = (-0.35, 0.08, -0.05, 0.02, -0.01)
    centres = {"R": (33.0, 24.0), "G1": (6.0, 25.0), "G2": (34.0, 4.0), "B": (5.0, 5.0)}
    fm = FlatModel(channels=("R", "G1", "G2", "B"), centre_px=centres, k={c: k for c in centres}, model_2d=None,
                   prnu=None, residual_rms={}, shape=FLAT_SHAPE, cfa_pattern="RGGB")
    g = fm.gain()
    assert g.dtype == np.float32
    corners = g[:, [0, 0, -1, -1], [0, -1, 0, -1]]
    assert fm.corner_gain() == {c: float(corners[i].min()) for i, c in enumerate(fm.channels)}
    held = fm.with_gain(np.full(g.shape, 0.5, np.float32)).gain()
    assert held.shape == g.shape and np.all(held == 0.5) and not held.flags.writeable


@pytest.mark.formula
def test_radial_gain_with_zero_coefficients_is_the_power_sum():
    """``radial_gain`` skips trailing zero coefficients; the values must stay those of g = 1 + Σ kᵢ r^(2i+2)
    (numpy's polyval, written out): no vignetting at all (every k = 0), a zero before a non-zero coefficient,
    and trailing zeros."""
    r2 = np.linspace(0.0, 1.0, 11)
    for k in ((0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.05), (-0.3, 0.0, 0.02), (-0.3, 0.05, 0.0, 0.0, 0.0), ()):
        np.testing.assert_allclose(radial_gain(r2, k), np.polynomial.polynomial.polyval(r2, [1.0, *k]),
                                   rtol=1e-15, atol=1e-15)


@pytest.mark.formula
def test_correct_flat_with_the_prnu_map():
    """``with_prnu=True`` divides by the radial gain times the PRNU map, the default by the gain alone: planes
    made by multiplying a known signal by both come back to it (float32: 2e-7)."""
    k = (-0.3, 0.05, 0.0, 0.0, 0.0)
    prnu = (1.0 + 0.02 * np.random.default_rng(3).standard_normal((4, *FLAT_SHAPE))).astype(np.float32)
    fm = _flat_model(k, (10.0, 20.0), prnu=prnu)
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    g = np.stack([_dng_radial_gain(c, 10.0, 20.0, k, xx, yy) for c in fm.channels])
    planes = np.full((4, *FLAT_SHAPE), 500.0)
    np.testing.assert_allclose(correct_flat(planes * g * prnu, fm, with_prnu=True), planes, rtol=2e-6)
    np.testing.assert_allclose(correct_flat(planes * g, fm), planes, rtol=2e-6)
