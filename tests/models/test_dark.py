"""Tests of :mod:`camcal.models.dark`.

Its formulas at non-trivial operating points, each checked against a value computed by other means (a
closed form, a published constant, exact synthetic data), never against the function under test.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.stats import chi2

from camcal.calibrate.dark import _channel_summary, fit_dark
from camcal.calibrate.dark_frames import DarkOptions, DarkStacks
from camcal.calibrate.dark_noise import TemporalNoise, temporal_noise
from camcal.errors import CamcalError, MissingMetadataError
from camcal.frame import PLANES, Exposure
from camcal.models.dark import DEAD, HOT, NOISY, DarkModel
from tests.helpers import (
    NOISE_METHOD,
    NORMAL_PER_MAD,
    _dark_group,
    _dark_model,
    _json_round_trip,
    _map_of_variance,
    _noisy_bound,
    _read_noise_stack,
    _stack,
)
from tests.oracles import (
    subtract_dark,
)


def _small_dark_model(planes=("R", "G1", "G2", "B"), known=True):
    """A small dark model with distinct values in every pixel, one unknown β uncertainty (inf) and defects."""
    n = len(planes)
    shape = (n, 2, 3)
    ramp = np.arange(np.prod(shape), dtype=np.float32).reshape(shape)
    unc = 0.01 * ramp + 0.5
    unc[1, 0, 2] = np.inf
    defects = np.zeros(shape, np.uint8)
    defects[0, 1, 1], defects[n - 1, 0, 0], defects[1, 1, 2] = 1, 2 | 4, 4
    channels = {p: {"bias_median_dn": 512.0 + k, "hot_pixel_count": int(np.count_nonzero(defects[k] & 1)),
                    "dead_pixel_count": int(np.count_nonzero(defects[k] & 2)),
                    "noisy_pixel_count": int(np.count_nonzero(defects[k] & 4))} for k, p in enumerate(planes)}
    return DarkModel(bias_dn=512.0 + ramp, dark_current_dn_per_s=(0.25 * ramp - 1.0) if known else None,
                     dark_current_unc_dn_per_s=unc if known else None, read_noise_dn=1.5 + 0.125 * ramp,
                     defects=defects, iso=800.0, cfa_pattern="RGGB" if n == 4 else None, temperature_c=21.5,
                     channels=channels, exposure_times_s=(0.001, 1.0, 30.0), black_level_dn=(512.0,) * n,
                     white_level_dn=15000.0, provenance={"files": ["a.dng"], "options": {"sigma": 5}})


@pytest.mark.formula
@pytest.mark.parametrize("planes", [("R", "G1", "G2", "B"), ("R", "G", "B")])
@pytest.mark.parametrize("known", [True, False])
def test_dark_record_round_trip_keeps_every_field(planes, known):
    """dark_to_parts -> JSON text for the record (maps as arrays) -> dark_from_parts gives back every map (float32,
    an unknown β uncertainty inf again, defects uint8) and every field; the record names the maps' units and
    counts the defects (hot 1, dead 1, noisy 2, here counted by hand)."""
    from camcal.models.dark import dark_from_parts, dark_to_parts

    m = _small_dark_model(planes, known)
    data, maps = dark_to_parts(m)
    names = ("bias", "dark_current", "dark_current_unc", "read_noise", "defects") if known else (
        "bias", "read_noise", "defects")
    assert sorted(maps) == sorted(f"{n}.{p}" for n in names for p in planes)
    if known:
        assert maps["dark_current_unc.G1" if len(planes) == 4 else "dark_current_unc.G"][0, 2] == np.float32(3e38)
        np.testing.assert_array_equal(maps[f"dark_current.{planes[2]}"], 0.25 * np.arange(12, 18).reshape(2, 3) - 1)
    np.testing.assert_array_equal(maps[f"bias.{planes[1]}"], 512.0 + np.arange(6, 12).reshape(2, 3))
    np.testing.assert_array_equal(maps[f"defects.{planes[0]}"], [[0, 0, 0], [0, 1, 0]])
    assert maps[f"defects.{planes[0]}"].dtype == np.float32
    assert data["iso"] == 800.0 and data["cfa_pattern"] == (None if len(planes) == 3 else "RGGB")
    assert data["layout"] == ("bayer" if len(planes) == 4 else "linear") and data["temperature_c"] == 21.5
    assert data["exposure_times_s"] == [0.001, 1.0, 30.0] and data["black_level_dn"] == [512.0] * len(planes)
    assert data["white_level_dn"] == 15000.0 and data["channels"] == m.channels
    assert data["dark_current_known"] is known and data["provenance"] == m.provenance
    assert data["units"] == {"bias": "DN", "dark_current": "DN s⁻¹ at iso", "dark_current_unc": "DN s⁻¹",
                             "read_noise": "DN", "defects": "bits: 1 hot, 2 dead, 4 noisy"}
    summ = data["summary"]
    assert (summ["hot_pixel_count"], summ["dead_pixel_count"], summ["noisy_pixel_count"]) == (1, 1, 2)
    assert summ["plane_shape"] == [2, 3] and summ["iso"] == 800.0

    back = dark_from_parts(_json_round_trip(data), {k: np.array(v) for k, v in maps.items()}, "d.json")
    for got, want in ((back.bias_dn, m.bias_dn), (back.read_noise_dn, m.read_noise_dn),
                      (back.dark_current_dn_per_s, m.dark_current_dn_per_s),
                      (back.dark_current_unc_dn_per_s, m.dark_current_unc_dn_per_s)):
        if want is None:
            assert got is None
            continue
        assert got.dtype == np.float32 and got.shape == (len(planes), 2, 3)
        np.testing.assert_array_equal(got, want)
    if known:
        assert back.dark_current_unc_dn_per_s[1, 0, 2] == np.inf
    assert back.defects.dtype == np.uint8
    np.testing.assert_array_equal(back.defects, m.defects)
    assert back.plane_names == planes
    assert (back.iso, back.cfa_pattern, back.temperature_c) == (m.iso, m.cfa_pattern, m.temperature_c)
    assert back.channels == m.channels and back.provenance == m.provenance
    assert back.exposure_times_s == (0.001, 1.0, 30.0) and back.black_level_dn == (512.0,) * len(planes)
    assert back.white_level_dn == 15000.0


@pytest.mark.formula
def test_dark_record_optional_fields_and_defects_read_from_floats():
    """Missing optional fields take their defaults (no CFA, no temperature, no times or levels, white level NaN);
    numbers given as text are read as numbers; defect bits stored as floats are rounded to the nearest integer."""
    from camcal.models.dark import dark_from_parts

    maps = {f"{m}.{p}": np.full((1, 2), 2.0, np.float32) for m in ("bias", "read_noise") for p in "RGB"}
    maps.update({f"defects.{p}": np.array([[0.9999, 4.0001]], np.float32) for p in "RGB"})
    data = {"iso": "200", "layout": "linear", "dark_current_known": False, "cfa_pattern": None,
            "exposure_times_s": ["0.5", 2], "black_level_dn": [64, "64", 64.5], "temperature_c": "19"}
    m = dark_from_parts(data, maps)
    assert m.iso == 200.0 and m.cfa_pattern is None and m.temperature_c == 19.0
    assert m.exposure_times_s == (0.5, 2.0) and m.black_level_dn == (64.0, 64.0, 64.5)
    assert m.dark_current_dn_per_s is None and m.dark_current_unc_dn_per_s is None
    np.testing.assert_array_equal(m.defects, np.tile(np.array([[1, 4]], np.uint8), (3, 1, 1)))
    m = dark_from_parts({"iso": 100, "layout": "linear", "dark_current_known": False}, maps)
    assert m.cfa_pattern is None and m.temperature_c is None and m.channels == {} and m.provenance == {}
    assert m.exposure_times_s == () and m.black_level_dn == () and np.isnan(m.white_level_dn)
    assert m.bias_dn.dtype == np.float32 and m.bias_dn.shape == (3, 1, 2)
    m = dark_from_parts({"iso": 100, "layout": "linear", "dark_current_known": False, "white_level_dn": 0,
                         "cfa_pattern": "GRBG"}, maps)
    assert np.isnan(m.white_level_dn) and m.cfa_pattern == "GRBG"  # 0 is no white level


@pytest.mark.formula
@pytest.mark.parametrize(("data", "drop", "says"), [
    ({"iso": 100}, "bias.G2", "dark model lacks maps bias.G2"),
    ({"iso": 100}, "dark_current.R", "dark model lacks maps dark_current.R"),
    ({"iso": 100, "dark_current_known": None}, "dark_current_unc.B", "dark model lacks maps dark_current_unc.B"),
    ({"iso": 100, "layout": "linear"}, None,
     "dark model lacks maps bias.G, dark_current.G, dark_current_unc.G, read_noise.G"),
    ({"cfa_pattern": "RGGB"}, None, "malformed dark model ('iso')"),
    ({"iso": "high"}, None, "malformed dark model (could not convert string to float: 'high')"),
    ({"iso": 100, "channels": 5}, None, "malformed dark model ("),
    (["iso", 100], None, "malformed dark model (list indices must be integers"),
])
def test_dark_record_refusals_name_the_file(data, drop, says):
    """A record lacking a map (the first four named) or with a malformed field: one line naming the file."""
    from camcal.models.dark import dark_from_parts

    maps = {f"{m}.{p}": np.ones((1, 2), np.float32) for m in ("bias", "dark_current", "dark_current_unc",
                                                               "read_noise", "defects") for p in PLANES4}
    maps.pop(drop, None)
    with pytest.raises(CamcalError) as e:
        dark_from_parts(data, maps, "cam/dark.json")
    assert str(e.value).startswith(f"cam/dark.json: {says}") and "\n" not in str(e.value)
    if "lacks maps" in says:  # the first four missing maps, no more
        assert str(e.value).split("lacks maps ")[1] == says.split("lacks maps ")[1]


PLANES4 = ("R", "G1", "G2", "B")


@pytest.mark.formula
def test_dead_pixels_join_the_dark_defect_map_with_their_counts_and_source():
    """Dead pixels (bit 2) are OR-ed into the defect map, other bits kept; each plane's dead count is the number
    of its pixels with bit 2 set, counted here with a loop; the source joins the provenance; a map of another
    shape is refused."""
    from camcal.models.dark import DEAD, with_dead_pixels

    m = _small_dark_model(("R", "G", "B"), True)
    dead = np.zeros(m.defects.shape, bool)
    dead[0, 1, 1] = dead[0, 0, 0] = dead[2, 1, 2] = True  # R: a hot pixel and a clean one; B: a noisy one
    out = with_dead_pixels(m, dead.astype(int) * 5, "flat.json")  # any non-zero value marks a dead pixel
    expect = m.defects.copy()
    for idx in zip(*np.nonzero(dead), strict=True):
        expect[idx] |= DEAD
    assert out.defects.dtype == np.uint8 and DEAD == 2
    np.testing.assert_array_equal(out.defects, expect)
    for k, p in enumerate(("R", "G", "B")):
        count = sum(1 for v in expect[k].ravel() if v & 2)
        assert out.channels[p] == {**m.channels[p], "dead_pixel_count": count}
    assert [out.channels[p]["dead_pixel_count"] for p in "RGB"] == [2, 0, 2]  # B had one dead pixel already
    assert out.provenance == {**m.provenance, "dead_pixels": "flat.json"}
    np.testing.assert_array_equal(out.bias_dn, m.bias_dn)
    assert m.provenance.get("dead_pixels") is None  # the model given is left as it was
    with pytest.raises(CamcalError) as e:
        with_dead_pixels(m, np.zeros((3, 2, 2), bool), "flat.json")
    assert str(e.value) == "dead-pixel map (3, 2, 2) does not match the dark model's (3, 2, 3)"


@pytest.mark.formula
def test_dark_frame_off_the_reference_iso_scales_beta_not_the_bias():
    """bias + β·t·(ISO/ISO_ref): at ISO 400 for a model measured at ISO 100, 12 s, β = 2.5 DN/s, bias 1024 DN:
    1024 + 2.5·12·4 = 1144 DN; a window returns the same pixels."""
    shape = (4, 6, 8)
    bias = np.full(shape, 1024.0, np.float32)
    bias[1, 2, 3] = 1030.0
    beta = np.full(shape, 2.5, np.float32)
    model = _dark_model(bias, beta, iso=100.0)
    frame = model.dark_frame_dn(12.0, iso=400.0)
    expect = bias + 2.5 * 12.0 * 4.0
    np.testing.assert_allclose(frame, expect, rtol=1e-7)
    np.testing.assert_allclose(model.dark_frame_dn(12.0), bias + 30.0, rtol=1e-7)
    np.testing.assert_allclose(model.dark_frame_dn(12.0, 400.0, (slice(1, 4), slice(2, 5))),
                               expect[:, 1:4, 2:5], rtol=1e-7)
    planes = expect + 500.0
    np.testing.assert_allclose(subtract_dark(planes, model, 12.0, iso=400.0), 500.0, rtol=1e-6)
    with pytest.raises(CamcalError, match="non-negative"):
        model.dark_frame_dn(-1.0)


@pytest.mark.formula
def test_temporal_noise_plane_means_chi_square_flags_and_read_noise_map():
    """Planes above 1 DN of noise (count 8, dof 7, noisy_sigma 3: the chi-square bound 5.79 is the larger),
    against values set by construction:

    - v̂ is the plain mean over the good, finite pixels, without their top 0.1 % when there are more than 1000:
      R has 1002 (1001 regular variances of 0, 2 and 3 DN², one of 500 DN² left out; the 0.999 quantile is 3 DN²
      exactly, so every pixel at 3 DN² stays), G1 has 1001 (the 500 left out), G2 exactly 1000 (the 500 kept),
      B is 1 DN² everywhere (exactly 1 DN of noise: not below 1 DN, no quantised fit). Defect pixels of
      10⁴ DN² and NaN variances (without a defect bit) are not in v̂.
    - a pixel is noisy where var > v̂·bound, for every pixel (defects too): probes at 0.995 and 1.005 of it;
    - the read-noise map is √(var − 1/12) clipped at 0 (0 DN² gives 0), NaN where var is NaN; no plane
      has a read noise or DSNU of its own (NaN).
    """
    shape = (4, 32, 32)
    dof, noisy_sigma = 7, 3.0
    bound = _noisy_bound(dof, noisy_sigma)
    assert bound == pytest.approx(5.7888, abs=1e-4)  # the chi-square branch; 1 + 3·√(2/7) = 2.60
    var = np.full((4, 1024), 1e4)
    defects = np.full((4, 1024), HOT, np.uint8)
    vhat = np.zeros(4)
    for k, n_good in enumerate((1002, 1001, 1000)):
        regular = np.resize([0.0, 2.0, 3.0], n_good - 1)
        var[k, : n_good - 1], var[k, n_good - 1] = regular, 500.0
        defects[k, :n_good] = 0
        vhat[k] = np.mean(regular) if n_good > 1000 else np.mean(np.append(regular, 500.0))
    var[3, :1000], defects[3, :1000], vhat[3] = 1.0, 0, 1.0
    var[0, 1002:1004], defects[0, 1002:1004] = np.nan, 0  # no variance: not a pixel of v̂, not a defect
    var[:, -2] = vhat * bound * 0.995  # defect pixels just under and over the bound
    var[:, -1] = vhat * bound * 1.005
    var, defects = var.reshape(shape), defects.reshape(shape)
    noise = temporal_noise(_read_noise_stack(var, dof + 1), var.copy(), defects, noisy_sigma)
    np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
    expect_noisy = np.greater(var, vhat[:, None, None] * bound, where=np.isfinite(var), out=np.zeros(shape, bool))
    np.testing.assert_array_equal(noise.noisy, expect_noisy)
    assert not noise.noisy[:, 31, 30].any() and noise.noisy[:, 31, 31].all()
    np.testing.assert_allclose(noise.read_noise_map_dn, _map_of_variance(var), rtol=1e-6, atol=0)
    assert noise.read_noise_map_dn[0, 0, 0] == 0.0  # a pixel of 0 DN² temporal variance
    assert np.all(np.isnan(noise.read_noise_dn)) and np.all(np.isnan(noise.dsnu_dn))
    np.testing.assert_array_equal(noise.quantised, False)
    assert noise.method == NOISE_METHOD


@pytest.mark.formula
def test_temporal_noise_bound_at_a_high_noisy_sigma_and_with_two_frames_or_one():
    """The other branches of the noisy-pixel bound, on 3 × 4 planes of 1.5, 2, 4 and 1.25 DN² (B: one good
    pixel, the rest defects), probes (defect pixels) at 0.995 and 1.005 of v̂·bound:

    - count 8 (dof 7), noisy_sigma 12: 1 + 12·√(2/7) = 7.41 is above the chi-square bound 5.79;
    - count 2 (dof 1): the chi-square bound χ²₁(1e-6) = 23.93 (two frames are a bias-only model's minimum);
    - count 1 (dof 0): no bound, no pixel is noisy, not even one of 10⁴ DN².
    """
    shape = (4, 3, 4)
    vhat = np.array([1.5, 2.0, 4.0, 1.25])
    defects = np.zeros(shape, np.uint8)
    defects[:, 2, 2:] = HOT
    defects[3] = HOT
    defects[3, 0, 0] = 0
    for count, noisy_sigma, bound in ((8, 12.0, 1 + 12 * np.sqrt(2 / 7)), (2, 6.0, 23.9281), (1, 6.0, None)):
        var = np.where(defects == 0, vhat[:, None, None], 1e4)
        if bound is not None:
            assert _noisy_bound(count - 1, noisy_sigma) == pytest.approx(bound, rel=1e-5)
            var[:, 2, 2] = vhat * bound * 0.995
            var[:, 2, 3] = vhat * bound * 1.005
        noise = temporal_noise(_read_noise_stack(var, count), var.copy(), defects, noisy_sigma)
        np.testing.assert_allclose(noise.temporal_noise_dn, np.sqrt(vhat), rtol=1e-6)
        expect = np.zeros(shape, bool) if bound is None else var > vhat[:, None, None] * bound
        np.testing.assert_array_equal(noise.noisy, expect, err_msg=f"count {count}")
        np.testing.assert_allclose(noise.read_noise_map_dn, _map_of_variance(var), rtol=1e-6)
        assert noise.method == NOISE_METHOD and not noise.quantised.any()


@pytest.mark.formula
def test_dark_model_summary_reports_its_maps_and_per_plane_figures():
    """The summary of a dark model against the model written out: its settings, the plane shape, each per-plane
    figure under its own name (the defect counts as ``*_count_per_plane``), and the totals of the defect map
    counted bit by bit with numpy (pixels with two bits count once in the fraction)."""
    shape = (4, 3, 5)
    defects = np.zeros(shape, np.uint8)
    for (k, i, j), bits in {(0, 0, 0): HOT, (0, 1, 2): HOT | NOISY, (1, 2, 4): DEAD, (2, 0, 1): NOISY,
                            (3, 1, 1): HOT | DEAD, (3, 2, 2): NOISY, (3, 2, 3): NOISY}.items():
        defects[k, i, j] = bits
    channels = {p: {"read_noise_dn": 0.4 + 0.1 * k, "dsnu_bias_dn": 0.25 * k,
                    "hot_pixel_count": int(np.sum(defects[k] & HOT > 0)),
                    "dead_pixel_count": int(np.sum(defects[k] & DEAD > 0)),
                    "noisy_pixel_count": int(np.sum(defects[k] & NOISY > 0))} for k, p in enumerate(PLANES)}
    bias = np.full(shape, 60.0, np.float32)
    model = DarkModel(bias_dn=bias, dark_current_dn_per_s=None, dark_current_unc_dn_per_s=None,
                      read_noise_dn=bias * 0 + 0.5, defects=defects, iso=200.0, cfa_pattern="BGGR",
                      temperature_c=31.5, channels=channels, exposure_times_s=(1e-4, 1.0, 8.0))
    expect = {
        "iso": 200.0, "cfa_pattern": "BGGR", "layout": "bayer", "temperature_c": 31.5,
        "exposure_times_s": [1e-4, 1.0, 8.0], "plane_shape": [3, 5],
        "read_noise_dn": {"R": 0.4, "G1": 0.5, "G2": 0.6000000000000001, "B": 0.7000000000000001},
        "dsnu_bias_dn": {"R": 0.0, "G1": 0.25, "G2": 0.5, "B": 0.75},
        "hot_pixel_count_per_plane": {"R": 2, "G1": 0, "G2": 0, "B": 1},
        "dead_pixel_count_per_plane": {"R": 0, "G1": 1, "G2": 0, "B": 1},
        "noisy_pixel_count_per_plane": {"R": 1, "G1": 0, "G2": 1, "B": 2},
        "hot_pixel_count": 3, "dead_pixel_count": 2, "noisy_pixel_count": 4,
        "defect_fraction": 7 / 60,
    }
    assert model.summary() == expect
    assert expect["defect_fraction"] == np.mean(defects != 0)


@pytest.mark.formula
def test_dark_line_fit_leaves_clipped_levels_out():
    """Per-pixel line fit level = b + β t with levels clipped at the white level: exact β and bias.

    Noise-free levels with integer bias and β and dyadic times are exact in float32, so the weighted least
    squares through the unclipped points returns the truth to rounding. A pixel saturated in every dark group
    (only its bias frame unsaturated) has no line: β is the bound (white − black)/t_min, its uncertainty
    infinite, and it is marked hot.
    """
    shape = (4, 6, 6)
    rng = np.random.default_rng(7)
    white, black = 4095.0, 1000.0
    bias = (black + rng.integers(-8, 9, shape)).astype(np.float64)
    beta = rng.integers(1, 4, shape).astype(np.float64)  # DN/s
    beta[0, 1, 1] = 160.0  # clips in the 20 s group only: 1008 + 160·8 < 4095 < 992 + 160·20
    beta[2, 3, 2] = 600.0  # clips at 20 s and 8 s
    beta[3, 4, 4] = 5000.0  # clips in every dark group
    times = (2.0**-13, 1.0, 8.0, 20.0)  # bias frames, then three dark groups
    stacks = [_stack(np.minimum(bias + beta * t, white), t, white, black) for t in times]
    model = fit_dark(DarkStacks(tuple((t, s) for t, s in zip(times[1:], stacks[1:], strict=True)), stacks[0]))
    fitted = np.ones(shape, bool)
    fitted[3, 4, 4] = False
    np.testing.assert_allclose(model.dark_current_dn_per_s[fitted], beta[fitted], rtol=1e-6)
    np.testing.assert_allclose(model.bias_dn[fitted], bias[fitted], rtol=0, atol=1e-3)
    assert model.defects[0, 1, 1] & HOT and model.defects[2, 3, 2] & HOT
    # saturated in all but one observation: the bounded-β branch
    assert model.dark_current_dn_per_s[3, 4, 4] == pytest.approx((white - black) / 1.0)
    assert model.bias_dn[3, 4, 4] == black
    assert np.isinf(model.dark_current_unc_dn_per_s[3, 4, 4])
    assert model.defects[3, 4, 4] & HOT
    # the clipped pixels' uncertainties come from their unclipped points only: finite
    assert np.all(np.isfinite(model.dark_current_unc_dn_per_s[[0, 2], [1, 3], [1, 2]]))


#: Standard error of a median over that of a mean for normal data, √(π/2) (the summary rounds it to 1.2533).
MEDIAN_PER_MEAN_SE = float(np.sqrt(np.pi / 2.0))


def _line_by_hand(points):
    """Per pixel, the frame-weighted least-squares line level = b + β t written out with numpy linear algebra.

    ``points``: ``(t, level, n, per_frame_variance)``, arrays broadcastable to one shape; a level at or above
    white − 1 must be given n = 0. Returns b, β, var(b), var(β) from A = (XᵀWX)⁻¹XᵀW and Cov = A diag(σ²/n) Aᵀ."""
    shape = np.broadcast_shapes(*(np.shape(a) for p in points for a in p))
    t, y, n, v = (np.stack([np.broadcast_to(np.asarray(p[i], float), shape) for p in points], -1) for i in range(4))
    x = np.stack([np.ones_like(t), t], -1)  # (..., m, 2)
    xtw = np.swapaxes(x, -1, -2) * n[..., None, :]
    m = xtw @ x
    line = np.count_nonzero(n > 0, axis=-1) >= 2  # else no line: NaN
    a = np.linalg.solve(np.where(line[..., None, None], m, np.eye(2)), xtw)  # (..., 2, m)
    coef = (a @ y[..., None])[..., 0]
    per = np.where(n > 0, v / np.where(n > 0, n, 1.0), 0.0)
    cov = (a * per[..., None, :]) @ np.swapaxes(a, -1, -2)
    out = coef[..., 0], coef[..., 1], cov[..., 0, 0], cov[..., 1, 1]
    return tuple(np.where(line, o, np.nan) for o in out)


def _plane_figures(k, b, b_var, beta, beta_var, defects, read_noise_var, gain, temporal, dsnu_bias2=None) -> dict:
    """The channel summary of plane k written out with numpy: EMVA 1288-style figures over the good pixels.

    The maps as the model holds them (float32 from :func:`fit_dark`, any float type here): the means and
    variances of their values in float64; the median of the β uncertainties as the model takes it, of the
    square roots in the maps' own type."""
    good = defects[k] == 0
    bk, betak = (np.asarray(a[k][good], np.float64) for a in (b, beta))
    b_var64, beta_var64 = (np.asarray(a[k][good], np.float64) for a in (b_var, beta_var))
    med = float(np.median(betak))
    mad = NORMAL_PER_MAD * float(np.median(np.abs(betak - med)))
    if dsnu_bias2 is None:  # spatial variance of the bias map minus the mean variance of its estimates
        dsnu_bias2 = float(np.var(bk)) - float(np.mean(b_var64))
    dsnu_beta2 = float(np.var(betak)) - float(np.mean(beta_var64))
    return {
        "bias_dn": float(np.mean(bk)),
        "bias_unc_dn": MEDIAN_PER_MEAN_SE * float(np.std(bk)) / np.sqrt(bk.size),
        "dark_current_dn_per_s": med,
        "dark_current_unc_dn_per_s": MEDIAN_PER_MEAN_SE * mad / np.sqrt(betak.size),
        "dark_current_pixel_unc_dn_per_s": float(np.median(np.sqrt(beta_var[k][good]))),
        "dark_current_mean_dn_per_s": float(np.mean(betak)),
        "read_noise_dn": float(np.sqrt(max(read_noise_var, 0.0))),
        "temporal_noise_dn": float(temporal),
        "dsnu_bias_dn": float(np.sqrt(max(dsnu_bias2, 0.0))),
        "dsnu_dark_current_dn_per_s": float(np.sqrt(max(dsnu_beta2, 0.0))),
        "gain_dn_per_e_from_dark": float(gain),
        "hot_pixel_count": int(np.sum((defects[k] & HOT) != 0)),
        "dead_pixel_count": int(np.sum((defects[k] & DEAD) != 0)),
        "noisy_pixel_count": int(np.sum((defects[k] & NOISY) != 0)),
    }


def _assert_figures(got: dict, expect: dict) -> None:
    """Every figure of one plane: the same keys; 1e-9 relative (float64 sums in another order), 1e-4 for the two
    uncertainties that use √(π/2) rounded to 1.2533 (1.1e-5 relative)."""
    assert set(got) == set(expect)
    for key, value in expect.items():
        rel = 1e-4 if key in ("bias_unc_dn", "dark_current_unc_dn_per_s") else 1e-9
        assert got[key] == pytest.approx(value, rel=rel, abs=1e-12), key
        assert type(got[key]) is (int if key.endswith("_count") else float), key


@pytest.mark.formula
def test_dark_channel_figures_per_plane_against_numpy():
    """``_channel_summary`` against the figures written out with numpy (``_plane_figures``) on random maps with
    hot, dead, noisy and doubly flagged pixels (whose wild values must not enter any figure):

    - read noise: with bias frames the plane mean of the temporal variance minus 1/12 DN²; without, that mean
      over each dark time extrapolated to t = 0 by a least-squares line written out (three times, two times),
      or the one time's mean; in a quantised plane (temporal noise below 1 DN) the quantised fit's value, and
      its DSNU for the bias DSNU (0.4 and 0.3 DN: the square, not twice the value, and not clamped at 1);
    - DSNU of the bias and of β: spatial variance minus the mean variance of the estimates, clamped at 0 (plane
      3's bias map is flatter than its estimates are uncertain); the DSNU of β is between 0 and 1 (DN/s)².
    """
    rng = np.random.default_rng(11)
    shape = (4, 5, 6)
    spread = np.array([3.0, 2.0, 1.5, 0.05])[:, None, None]
    b = 1000.0 + spread * rng.standard_normal(shape)
    b_var = rng.uniform(0.01, 0.05, shape)
    beta = 2.0 + 0.3 * rng.standard_normal(shape)
    beta_var = rng.uniform(0.001, 0.004, shape)
    var_t = rng.uniform(3.5, 4.5, shape)
    defects = np.zeros(shape, np.uint8)
    for (k, y, x), flag in {(0, 1, 1): HOT, (1, 2, 3): NOISY, (2, 0, 5): DEAD, (3, 4, 0): HOT | NOISY,
                            (1, 4, 4): HOT | DEAD, (2, 3, 2): HOT}.items():
        defects[k, y, x] = flag
        b[k, y, x], beta[k, y, x], var_t[k, y, x] = 5000.0, 900.0, 400.0
        b_var[k, y, x] = beta_var[k, y, x] = 50.0
    gain = np.array([0.3, 0.4, 0.5, 0.6])[:, None, None]
    temporal = np.array([0.6, 2.0, 2.1, 1.9])
    noise = TemporalNoise(temporal_noise_dn=temporal, read_noise_dn=np.array([0.4, np.nan, np.nan, np.nan]),
                          dsnu_dn=np.array([0.3, np.nan, np.nan, np.nan]), quantised=temporal < 1.0,
                          noisy=(defects & NOISY) != 0, read_noise_map_dn=np.sqrt(var_t), method="test")
    times = (0.5, 2.0, 8.0)
    stacks = []
    for t in times:  # plane means of the temporal variance curved in t (a line through them is not exact)
        v = var_t + 0.5 * t + 0.1 * t * t + rng.uniform(-0.2, 0.2, shape)
        stacks.append((t, _dark_group(b + beta * t, v, t, 8)))

    def extrapolated(k, sts):
        good = defects[k] == 0
        ts = np.array([t for t, _ in sts])
        vs = np.array([np.mean(np.asarray(s.variance_all[k][good], np.float64)) for _, s in sts])
        if ts.size == 1:
            return vs[0]
        slope = np.sum((ts - ts.mean()) * (vs - vs.mean())) / np.sum((ts - ts.mean()) ** 2)
        return vs.mean() - slope * ts.mean()

    maps32 = tuple(a.astype(np.float32) for a in (b, b_var, beta, beta_var))  # the dark fit's maps are float32
    for have_bias, sts in ((True, stacks), (False, stacks), (False, stacks[:2]), (False, stacks[:1])):
        got = _channel_summary(b, b_var, beta, beta_var, var_t, defects, sts, have_bias, gain, noise, PLANES)
        got32 = _channel_summary(*maps32[:2], *maps32[2:], var_t, defects, sts, have_bias, gain, noise, PLANES)
        assert list(got) == list(PLANES)
        for k, name in enumerate(PLANES):
            if k == 0:
                rn_var, dsnu2 = 0.4**2, 0.3**2
            elif have_bias:
                rn_var, dsnu2 = float(np.mean(var_t[k][defects[k] == 0])) - 1.0 / 12.0, None
            else:
                rn_var, dsnu2 = extrapolated(k, sts) - 1.0 / 12.0, None
            expect = _plane_figures(k, b, b_var, beta, beta_var, defects, rn_var, gain[k, 0, 0], temporal[k], dsnu2)
            _assert_figures(got[name], expect)
            # float32 maps: their means and variances taken in float64 all the same (float32 sums of ~1000 DN
            # values differ by about 1e-7 relative)
            expect = _plane_figures(k, *maps32[:2], *maps32[2:], defects, rn_var, gain[k, 0, 0], temporal[k], dsnu2)
            _assert_figures(got32[name], expect)
    # the guards: 0 < DSNU² of β < 1 in every plane, the bias DSNU² of plane 3 negative before its clamp
    for k in range(4):
        good = defects[k] == 0
        assert 0 < float(np.var(beta[k][good]) - np.mean(beta_var[k][good])) < 1
    assert float(np.var(b[3][defects[3] == 0]) - np.mean(b_var[3][defects[3] == 0])) < 0


def _hot_noisy_by_hand(beta, var_t, dof, hot_sigma=6.0, hot_factor=5.0, noisy_sigma=6.0):
    """The documented defect rules written out: hot if β is not finite or above median + max(hot_sigma robust σ,
    (hot_factor − 1)|median|) of its plane; noisy if the temporal variance is above the plane's mean over the
    non-hot pixels times max(χ²_{1e-6}(dof)/dof, 1 + noisy_sigma √(2/dof))."""
    defects = np.zeros(beta.shape, np.uint8)
    bound = max(float(chi2.isf(1e-6, dof)) / dof, 1.0 + noisy_sigma * np.sqrt(2.0 / dof))
    for k in range(beta.shape[0]):
        fin = beta[k][np.isfinite(beta[k])]
        med = np.median(fin)
        rs = NORMAL_PER_MAD * np.median(np.abs(fin - med))
        hot = ~np.isfinite(beta[k]) | (beta[k] > med + max(hot_sigma * rs, (hot_factor - 1.0) * abs(med)))
        vhat = np.mean(var_t[k][~hot])
        defects[k] = np.where(hot, HOT, 0) | np.where(var_t[k] > vhat * bound, NOISY, 0)
    return defects


@pytest.mark.formula
def test_dark_fit_with_bias_frames_and_one_dark_time_against_numpy(tmp_path):
    """``fit_dark`` on bias frames (16, exposure time not recorded: t = 0) and one dark time (4 frames at
    0.5 s), every output against values written out in the test:

    - b and β: the line through the two exact levels; the pixel saturated at 0.5 s has no line: β is the bound
      (white − black)/0.5 s, b the black level, its uncertainty infinite, and it is hot;
    - var(β): the least-squares covariance (``_line_by_hand``) with the per-frame variances of the noise line
      v0 + g·max(level − b, 0), v0 = 4 DN², g = 0.5 DN/e⁻ (each pixel's temporal variance lies on it; the two
      noisy pixels are more than 5× the plane and left out of it); the bias level's signal is 0, not 1 DN, and
      measured from each pixel's own bias, not the black level, also in the plane of the unfitted pixel;
    - hot pixels at the documented threshold median + max(6 robust σ, 4·median) = 10 DN/s in plane 0 (β = 9 and
      exactly 10 are not hot, 13 and 40 are); noisy pixels against the χ² bound of the bias frames' 15 degrees
      of freedom (the 6× pixel of plane 3 is noisy at 15, not at the 3 of the dark frames);
    - the read-noise map √(var − 1/12), every field of the model and its float32 maps, the channel figures (read
      noise from the bias frames), the temperature (mean and range of the dark frames'), the provenance;
    - a bias-only fit of the same bias frames, and frames at two ISO settings refused.
    """
    shape = (4, 6, 8)
    rng = np.random.default_rng(5)
    black, white, t, v0, g = (1000.0, 1002.0, 998.0, 1001.0), 4095.0, 0.5, 4.0, 0.5
    blk = np.asarray(black)[:, None, None]
    bias = blk + rng.integers(-8, 9, shape)
    beta = 2.0 + 0.25 * rng.integers(-1, 2, shape)
    beta[0, 0, :4] = (9.0, 10.0, 13.0, 40.0)
    beta[2, 5, 7] = 8000.0  # saturated at 0.5 s: no line
    level = np.minimum(bias + beta * t, white)
    var_dark = np.where(level >= white, 0.0, v0 + g * beta * t)
    var_bias = np.full(shape, v0)
    var_bias[1, 3, 3] = 100.0 * v0  # noisy
    var_bias[3, 2, 6] = 6.0 * v0  # noisy against the bound of 15 degrees of freedom only
    bias_st = _dark_group(bias, var_bias, 0.0, 16, black=black, exposure_s=None, temps=[30.0] * 16)
    dark_st = _dark_group(level, var_dark, t, 4, black=black, temps=(21.0, 21.5, 22.0, 23.5))
    dark_folder, bias_folder = tmp_path / "dark", tmp_path / "bias"
    stacks = DarkStacks(((t, dark_st),), bias_st, dark_folder, bias_folder, ("d1.dng", "d2.dng"), ("b1.dng",))
    model = fit_dark(stacks)

    fitted = np.ones(shape, bool)
    fitted[2, 5, 7] = False
    b_fit = np.where(fitted, bias, blk)
    weights = np.where(level < white - 1.0, 4.0, 0.0)
    points = [(0.0, bias, 16.0, np.full(shape, v0)),  # the bias level: no dark signal
              (t, level, weights, v0 + g * np.maximum(level - bias, 0.0))]
    e_b, e_beta, e_bvar, e_betavar = _line_by_hand(points)
    e_beta = np.where(fitted, e_beta, (white - blk) / t)
    e_betavar = np.where(fitted, e_betavar, np.inf)
    np.testing.assert_allclose(model.bias_dn, b_fit, rtol=0, atol=1e-9)
    np.testing.assert_allclose(e_beta[fitted], beta[fitted], rtol=1e-12)
    np.testing.assert_allclose(model.dark_current_dn_per_s, e_beta, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_unc_dn_per_s, np.sqrt(e_betavar), rtol=1e-6)  # float32 maps
    np.testing.assert_allclose(model.read_noise_dn, np.sqrt(var_bias - 1.0 / 12.0), rtol=1e-6)
    for a in (model.bias_dn, model.dark_current_dn_per_s, model.dark_current_unc_dn_per_s, model.read_noise_dn):
        assert a.dtype == np.float32
    e_defects = _hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_bias, 15.0)
    np.testing.assert_array_equal(model.defects, e_defects)
    # plane 0's threshold is exactly 10 DN/s: median 2, 6 robust σ = 6 × 0.25 × 1.4826 < 4 × 2
    assert np.median(beta[0]) == 2.0 and np.median(np.abs(beta[0] - 2.0)) == 0.25
    assert e_defects[0, 0, :4].tolist() == [0, 0, HOT, HOT] and e_defects[2, 5, 7] & HOT
    assert e_defects[1, 3, 3] == NOISY and e_defects[3, 2, 6] == NOISY
    assert not (_hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_bias, 3.0)[3, 2, 6] & NOISY)

    assert model.iso == 100.0 and model.cfa_pattern == "RGGB" and model.exposure_times_s == (0.5,)
    assert model.black_level_dn == black and model.white_level_dn == white
    assert model.temperature_c == pytest.approx(22.0, rel=1e-12)
    for k, name in enumerate(PLANES):
        good = e_defects[k] == 0
        rn_var = float(np.mean(var_bias[k][good])) - 1.0 / 12.0
        # of the maps as the model stores them (float32)
        expect = _plane_figures(k, *(a.astype(np.float32) for a in (b_fit, e_bvar, e_beta, e_betavar)), e_defects,
                                rn_var, g,
                                np.sqrt(np.mean(var_bias[k][(e_defects[k] & HOT) == 0])))
        _assert_figures(model.channels[name], expect)
    assert model.provenance == {
        "dark_folder": str(dark_folder), "bias_folder": str(bias_folder), "dark_files": ["d1.dng", "d2.dng"],
        "bias_files": ["b1.dng"], "frames_per_exposure": {"0.5": 4}, "temperature_range_c": [21.0, 23.5],
        "options": {"method": "sigma_clip", "sigma": 3.0, "hot_sigma": 6.0, "hot_factor": 5.0, "noisy_sigma": 6.0,
                    "saturation_fraction": 0.01, "bias_prior_frames": 1.0},
        "read_noise_method": "per-pixel temporal variance minus the quantisation variance 1/12 DN² (EMVA 1288 eq. 4)",
        "bias_source": "bias frames", "read_noise_source": "bias frames", "black_level_source": "file"}

    # bias only: the bias frames' own model, with the options and folder given
    only = fit_dark(DarkStacks((), bias_st, bias_folder=bias_folder), DarkOptions(hot_sigma=7.0))
    assert only.dark_current_dn_per_s is None
    np.testing.assert_array_equal(only.bias_dn, bias)
    assert only.provenance["bias_folder"] == str(bias_folder) and only.provenance["options"]["hot_sigma"] == 7.0
    # bias frames at another ISO than the darks: refused, naming the dark folder
    with pytest.raises(CamcalError, match="mix ISO") as err:
        fit_dark(replace(stacks, bias=_dark_group(bias, var_bias, 0.0, 16, black=black, iso=200.0)))
    assert err.value.path == dark_folder
    # a frame without an ISO: named in the error
    nameless = replace(dark_st, exposures=(Exposure(exposure_s=t, iso=None),) + dark_st.exposures[1:])
    with pytest.raises(MissingMetadataError) as err:
        fit_dark(replace(stacks, darks=((t, nameless),)))
    assert err.value.path == dark_st.paths[0]


@pytest.mark.formula
def test_dark_fit_without_bias_frames_takes_the_black_level_as_a_prior(tmp_path):
    """``fit_dark`` on dark frames alone at 0.5, 2 and 8 s (16, 4 and 6 frames), the black level a prior
    point at t = 0 worth 2 frames, against values written out in the test:

    - b and β: the frame-weighted least squares through the prior and the three levels (``_line_by_hand``); the
      levels lie on the line b = black level, so the fit returns the truth, and a prior at another time or
      weight would not; the pixel saturated at every time has the β bound (white − black)/0.5 s;
    - var(β) with the noise line v0 = 4 DN², g = 0.5 DN/e⁻ through the three dark times;
    - the read noise extrapolated to t = 0 from the plane means of the shortest darks (v0 − 1/12 by
      construction), the read-noise map of the shortest darks, noisy pixels against the χ² bound of the shortest
      darks' 15 degrees of freedom; no CFA pattern; temperature unknown when a frame has none; the provenance.
    """
    shape = (4, 6, 8)
    rng = np.random.default_rng(6)
    black, white, v0, g = (1000.0, 1002.0, 998.0, 1001.0), 4095.0, 4.0, 0.5
    blk = np.broadcast_to(np.asarray(black)[:, None, None], shape)
    beta = 2.0 + 0.25 * rng.integers(-1, 2, shape)
    beta[0, 1, 2] = 40.0
    beta[2, 5, 7] = 8000.0  # saturated at every time: no line
    groups = ((0.5, 16), (2.0, 4), (8.0, 6))
    darks, points = [], [(0.0, blk, 2.0, v0)]
    for t, n in groups:
        level = np.minimum(blk + beta * t, white)
        var = np.where(level >= white, 0.0, v0 + g * beta * t)
        if t == 0.5:
            var[3, 2, 6] *= 8.0  # noisy against 15 degrees of freedom, not against the 3 of the 2 s darks
            var_t = var.copy()
        temps = [20.0] * n if t < 8.0 else [None] * n
        darks.append((t, _dark_group(level, var, t, n, black=black, cfa=None, temps=temps)))
        points.append((t, level, np.where(level < white - 1.0, n, 0.0), v0 + g * np.maximum(level - blk, 0.0)))
    model = fit_dark(DarkStacks(tuple(darks), None, tmp_path / "dark"), DarkOptions(bias_prior_frames=2.0))

    fitted = np.ones(shape, bool)
    fitted[2, 5, 7] = False
    e_b, e_beta, e_bvar, e_betavar = _line_by_hand(points)
    e_b = np.where(fitted, e_b, blk)
    e_beta = np.where(fitted, e_beta, (white - blk) / 0.5)
    e_betavar = np.where(fitted, e_betavar, np.inf)
    np.testing.assert_allclose(e_b[fitted], blk[fitted], rtol=1e-12)
    np.testing.assert_allclose(e_beta[fitted], beta[fitted], rtol=1e-12)
    np.testing.assert_allclose(model.bias_dn, e_b, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_dn_per_s, e_beta, rtol=1e-7)
    np.testing.assert_allclose(model.dark_current_unc_dn_per_s, np.sqrt(e_betavar), rtol=1e-6)
    # the saturated pixel's variance is 0: its read noise is floored at 0, not NaN; computed in float64 from the
    # float32 variances as stacked and stored in float32 (float32 arithmetic differs in the last bit here)
    e_rn = np.sqrt(np.maximum(var_t.astype(np.float32).astype(np.float64) - 1.0 / 12.0, 0.0)).astype(np.float32)
    np.testing.assert_array_equal(model.read_noise_dn, e_rn)
    e_defects = _hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_t, 15.0)
    np.testing.assert_array_equal(model.defects, e_defects)
    assert e_defects[0, 1, 2] == HOT and e_defects[2, 5, 7] == HOT and e_defects[3, 2, 6] == NOISY
    assert not (_hot_noisy_by_hand(np.where(fitted, beta, np.nan), var_t, 3.0)[3, 2, 6] & NOISY)
    assert model.cfa_pattern is None and model.temperature_c is None and model.exposure_times_s == (0.5, 2.0, 8.0)
    for k, name in enumerate(PLANES):
        good = e_defects[k] == 0
        ts = np.array([t for t, _ in groups])
        vs = np.array([np.mean(np.asarray(st.variance_all[k][good], np.float64)) for _, st in darks])
        slope = np.sum((ts - ts.mean()) * (vs - vs.mean())) / np.sum((ts - ts.mean()) ** 2)
        rn_var = vs.mean() - slope * ts.mean() - 1.0 / 12.0
        assert rn_var == pytest.approx(v0 - 1.0 / 12.0, rel=1e-9)
        expect = _plane_figures(k, *(a.astype(np.float32) for a in (e_b, e_bvar, e_beta, e_betavar)), e_defects,
                                rn_var, g,
                                np.sqrt(np.mean(var_t[k][(e_defects[k] & HOT) == 0])))
        _assert_figures(model.channels[name], expect)
    prov = model.provenance
    assert prov["bias_folder"] is None and prov["temperature_range_c"] is None
    assert prov["frames_per_exposure"] == {"0.5": 16, "2": 4, "8": 6}
    assert prov["bias_source"] == "fit of dark frames, black level as prior"
    assert prov["read_noise_source"] == "shortest dark (0.5 s), per-plane value extrapolated to t = 0"
