"""Profile: calibrate a synthetic session, recover the truth, save/load, contract, tampering."""

import json
import zipfile

import numpy as np
import pytest

from camcal.errors import CamcalError
from camcal.io.container import JSON_MEMBER, MAPS_MEMBER
from camcal.models.profile import SCHEMA_VERSION, contract, diff_profiles, load_profile, save_profile
from camcal.units import SPECTRAL_SENSITIVITY
from tests.conftest import assert_one_line_error, run_cli


@pytest.fixture(scope="module")
def shown(profile_path):
    proc = run_cli("profile", "show", "--json", profile_path)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_contract_keys(shown):
    c = shown
    assert c["camera"]["make"] == "camcal" and c["camera"]["model"] == "Synthetic D5100"
    assert c["camera"]["cfa_pattern"] == "RGGB"
    assert c["reference"] == {"iso": 100.0, "f_number": 4.0}
    for key in ("bias_dn", "dark_current_dn_per_s", "read_noise_dn"):
        assert set("RGB") <= set(c["dark"][key])
    assert isinstance(c["dark"]["hot_pixel_count"], int)
    for key in ("gamma", "alpha"):
        assert set("RGB") <= set(c["response"][key])
    s = c["spectral_sensitivity"]
    n = len(s["wavelength_nm"])
    assert n == 61 and all(len(s[k]) == n for k in ("R", "G", "B", "R_unc", "G_unc", "B_unc"))
    assert s["units"] == SPECTRAL_SENSITIVITY
    # G is the mean of G1 and G2
    assert c["dark"]["bias_dn"]["G"] == pytest.approx(0.5 * (c["dark"]["bias_dn"]["G1"] + c["dark"]["bias_dn"]["G2"]))


def test_calibrate_recovers_truth(shown, truth):
    """Tolerances are the stage issues' (β 2 %, read noise 3 %, γ 0.5 %, c(λ) 3 % of peak absolute)."""
    d = shown["dark"]
    for ch in ("R", "G1", "G2", "B"):
        assert d["dark_current_dn_per_s"][ch] == pytest.approx(truth["dark_current_dn_per_s"][ch], rel=0.02)
        assert d["read_noise_dn"][ch] == pytest.approx(truth["read_noise_dn"][ch], rel=0.03)
        assert d["bias_dn"][ch] == pytest.approx(truth["bias_dn"][ch], abs=0.1)
    assert d["hot_pixel_count"] >= 0.95 * truth["hot_pixel_count"]
    assert d["hot_pixel_count"] <= truth["hot_pixel_count"] + 0.001 * 4 * 128 * 192
    for ch in ("R", "G", "B"):
        assert shown["response"]["gamma"][ch] == pytest.approx(1.0, abs=0.005)
    # flat: corner gain of the truth model (k sum), centre within a plane pixel
    assert shown["flat"]["corner_gain"]["G"] == pytest.approx(truth["vignetting"]["corner_gain"], abs=0.01)
    cx, cy = truth["vignetting"]["centre_px"]
    for ch, (x, y) in shown["flat"]["centre_full_px"].items():
        assert abs(x - cx) < 2 and abs(y - cy) < 2, ch
    # c(λ): absolute, against the true curve sampled at the sweep wavelengths
    s = shown["spectral_sensitivity"]
    wl_true = np.asarray(truth["spectral_sensitivity"]["wavelength_nm"])
    for ch in ("R", "G", "B"):
        true = np.interp(s["wavelength_nm"], wl_true, truth["spectral_sensitivity"][ch])
        rms = np.sqrt(np.mean((np.asarray(s[ch]) - true) ** 2)) / true.max()
        assert rms < 0.03, (ch, rms)


def test_save_load_identical(profile_path, tmp_path):
    a = load_profile(profile_path)
    b = save_profile(a, tmp_path / "again.camcal")
    c = load_profile(tmp_path / "again.camcal")
    assert b.content_sha256 == a.content_sha256 == c.content_sha256
    assert diff_profiles(a, c) == []
    assert contract(a) == contract(c)
    np.testing.assert_array_equal(a.dark.bias_dn, c.dark.bias_dn)
    np.testing.assert_array_equal(a.flat.gain(), c.flat.gain())
    np.testing.assert_array_equal(a.spectral.values["R"], c.spectral.values["R"])


def _rewrite_json(src, dst, edit):
    with zipfile.ZipFile(src) as zf:
        doc = json.loads(zf.read(JSON_MEMBER))
        maps = zf.read(MAPS_MEMBER)
    edit(doc)
    with zipfile.ZipFile(dst, "w") as zf:
        zf.writestr(JSON_MEMBER, json.dumps(doc))
        zf.writestr(MAPS_MEMBER, maps)


def test_tampered_number_is_refused(profile_path, tmp_path):
    bad = tmp_path / "edited.camcal"
    _rewrite_json(profile_path, bad, lambda d: d["reference"].update(iso=200.0))
    assert_one_line_error(run_cli("profile", "show", bad), "edited.camcal", "hash mismatch")


def test_unknown_version_is_refused(profile_path, tmp_path):
    from camcal.io.container import content_hash

    def bump(d):
        d["schema_version"] = "2.0"
        d["integrity"]["content_sha256"] = content_hash(d)

    bad = tmp_path / "v2.camcal"
    _rewrite_json(profile_path, bad, bump)
    assert_one_line_error(run_cli("profile", "show", bad), "v2.camcal", "2.0", "not supported")


def test_schema_violation_with_valid_hash_is_refused(profile_path, tmp_path):
    from camcal.io.container import content_hash

    def corrupt(d):
        d["reference"]["iso"] = "a hundred"
        d["integrity"]["content_sha256"] = content_hash(d)

    bad = tmp_path / "schema.camcal"
    _rewrite_json(profile_path, bad, corrupt)
    assert_one_line_error(run_cli("profile", "show", bad), "schema.camcal", "reference/iso")


def test_truncated_profile_is_refused(profile_path, tmp_path):
    bad = tmp_path / "cut.camcal"
    data = profile_path.read_bytes()
    bad.write_bytes(data[: len(data) // 2])
    assert_one_line_error(run_cli("profile", "show", bad), "cut.camcal")


def test_schema_version_constant():
    assert SCHEMA_VERSION.split(".")[0] == "1"


def test_diff_shows_changes(profile_path, tmp_path, session_dir):
    proc = run_cli("calibrate", session_dir, "-o", tmp_path / "rel.camcal", "--sweep-mode", "relative")
    assert proc.returncode == 0, proc.stderr
    proc = run_cli("profile", "diff", "--json", profile_path, tmp_path / "rel.camcal")
    rows = json.loads(proc.stdout)
    keys = {r["key"] for r in rows}
    assert "spectral_sensitivity.units" in keys and "spectral_sensitivity.R" in keys
    assert not any(k.startswith("dark.") for k in keys)


def test_light_load_verifies_but_does_not_decode_maps(profile_path, tmp_path):
    """``with_maps=False`` (a batch runner's preflight): same identity and hash, no dark/flat stage,
    the spectral stage intact; a profile with damaged maps is still refused."""
    full = load_profile(profile_path)
    light = load_profile(profile_path, with_maps=False)
    assert light.content_sha256 == full.content_sha256 and light.camera == full.camera
    assert full.dark is not None and full.flat is not None
    assert light.dark is None and light.flat is None
    assert light.spectral is not None and light.response is not None
    for a, b in zip(light.spectral.rgb().values(), full.spectral.rgb().values(), strict=True):
        np.testing.assert_array_equal(a, b)
    with zipfile.ZipFile(profile_path) as zf:
        j, m = zf.read(JSON_MEMBER), bytearray(zf.read(MAPS_MEMBER))
    m[len(m) // 2] ^= 0x01
    bad = tmp_path / "bad.camcal"
    with zipfile.ZipFile(bad, "w") as zf:
        zf.writestr(JSON_MEMBER, j)
        zf.writestr(MAPS_MEMBER, bytes(m))
    with pytest.raises(CamcalError, match="maps hash mismatch"):
        load_profile(bad, with_maps=False)


# ---- strict schema inside sections (issue 19) -------------------------------------------------------------------
def _rehashed_copy(src, dst, edit):
    from camcal.io.container import content_hash

    def both(d):
        edit(d)
        d["integrity"]["content_sha256"] = content_hash(d)

    _rewrite_json(src, dst, both)
    return dst


def _node(doc, path):
    for k in path:
        doc = doc[k]
    return doc


# every object camcal reads back, at every depth (the response path depends on what the session calibrated)
STRICT_PATHS = (
    ("camera",), ("reference",), ("dark",), ("dark", "channels", "G1"), ("dark", "units"), ("flat",),
    ("flat", "centre_px"), ("response",), ("response", "raw"), ("response", "raw", "channels", "G2"),
    ("response", "processed", "tone"), ("response", "processed", "tone", "channels", "G"),
    ("response", "processed", "tone", "channels", "G", "srgb"), ("response", "processed", "colour_matrix"),
    ("spectral_sensitivity",), ("spectral_sensitivity", "values"), ("provenance",), ("provenance", "inputs", 0),
    ("integrity",),
)


@pytest.mark.parametrize("path", STRICT_PATHS, ids=["/".join(map(str, p)) for p in STRICT_PATHS])
def test_unknown_key_in_a_section_is_refused_naming_it(profile_path, tmp_path, path):
    with zipfile.ZipFile(profile_path) as zf:
        if _node_or_none(json.loads(zf.read(JSON_MEMBER)), path) is None:
            pytest.skip(f"{path} not in this profile")
    bad = _rehashed_copy(profile_path, tmp_path / "extra.camcal",
                         lambda d: _node(d, path).update(surprise=1))
    key = "/".join(map(str, path)) + "/surprise"
    with pytest.raises(CamcalError, match=f"unknown key {key} ") as err:
        load_profile(bad)
    assert "extra.camcal" in str(err.value) and "\n" not in str(err.value)


def _node_or_none(doc, path):
    try:
        return _node(doc, path)
    except (KeyError, IndexError, TypeError):
        return None


def test_unknown_key_cli_one_line(profile_path, tmp_path):
    bad = _rehashed_copy(profile_path, tmp_path / "extra.camcal", lambda d: d["dark"].update(beta_source="x"))
    assert_one_line_error(run_cli("profile", "show", bad), "extra.camcal", "unknown key dark/beta_source")


def test_newer_minor_version_with_new_keys_says_so(profile_path, tmp_path):
    def newer(d):
        d["schema_version"] = "1.99"
        d["camera"]["lens"] = "50 mm"

    bad = _rehashed_copy(profile_path, tmp_path / "newer.camcal", newer)
    with pytest.raises(CamcalError, match="unknown key camera/lens .*1.99 is newer.*use a newer camcal"):
        load_profile(bad)


def test_schema_1_0_profile_still_loads(profile_path, tmp_path):
    """A profile as camcal 1.0 wrote it (no colour matrix, version 1.0) loads under the strict schema; the
    informational records stay free-form (they are never read back)."""
    def as_1_0(d):
        d["schema_version"] = "1.0"
        if d["response"] and d["response"].get("processed"):
            d["response"]["processed"].pop("colour_matrix", None)
        d["dark"]["summary"]["written_by"] = "an older camcal"
        d["flat"]["info"]["anything"] = {"nested": [1, 2]}

    old = load_profile(_rehashed_copy(profile_path, tmp_path / "old.camcal", as_1_0))
    assert old.schema_version == "1.0" and old.dark is not None and old.flat is not None


def test_profile_without_stages_follows_the_schema():
    from camcal.models.profile import CalibrationProfile, CameraIdentity, profile_to_document, validate_document

    p = CalibrationProfile(CameraIdentity("m", "x", None, "RGGB", 96, 64), 100.0, 4.0)
    doc, maps = profile_to_document(p)
    assert maps == {} and all(doc[k] is None for k in ("dark", "flat", "response", "spectral_sensitivity"))
    validate_document({**doc, "integrity": {"algorithm": "sha256", "content_sha256": "0" * 64,
                                            "maps_sha256": None}}, "p.camcal")
