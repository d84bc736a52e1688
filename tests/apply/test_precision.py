"""``camcal apply --precision float|half|mixed`` and ``--compression`` (issue 28): the pixel type written, half's
rounding bound, resuming."""

from __future__ import annotations

import numpy as np
import OpenImageIO as oiio

from camcal.io.exr import read_exr, read_exr_header
from camcal.models.spectra import gaussian_line
from camcal.synth.camera import Scene
from tests.conftest import assert_one_line_error, run_cli


def _spec(path) -> tuple[str, str]:
    """(pixel type, compression) of an EXR, read with OpenImageIO itself."""
    inp = oiio.ImageInput.open(str(path))
    try:
        spec = inp.spec()
        return str(spec.format), str(spec.getattribute("compression"))
    finally:
        inp.close()


def _pixel_type(path) -> str:
    return _spec(path)[0]


def _write_photo(camera, tmp_path, name: str, seed: int):
    """A DNG of a uniform 663 nm line at the profile's reference setting, in ``tmp_path/photos``."""
    photo = tmp_path / "photos" / name
    photo.parent.mkdir(exist_ok=True)
    camera.write_dng(photo, Scene.uniform(1.3 * gaussian_line(663.0, 5.0)), exposure_s=0.02, iso=100, f_number=4.0,
                     rng=np.random.default_rng(seed))
    return photo


def _apply_each(tmp_path, profile_path, photo, precisions) -> None:
    """``camcal apply`` of ``photo`` once per precision, each into ``tmp_path/<precision>``."""
    for prec in precisions:
        proc = run_cli("apply", profile_path, photo, "-o", tmp_path / prec, "--precision", prec, "--jobs", "1")
        assert proc.returncode == 0, proc.stderr


def test_precision_half_against_float(tmp_path, camera, profile_path):
    photo = _write_photo(camera, tmp_path, "h.dng", 3)
    _apply_each(tmp_path, profile_path, photo, ("float", "half"))
    f = tmp_path / "float" / "h.dng.exr"
    h = tmp_path / "half" / "h.dng.exr"
    assert _pixel_type(f) == "float" and _pixel_type(h) == "half"
    cf, _ = read_exr(f)
    ch, _ = read_exr(h)
    for name in ("R", "G", "B", "L663"):
        ok = np.isfinite(cf[name]) & (cf[name] > 6.2e-5)  # half's normal range: relative rounding holds there
        rel = np.abs(ch[name][ok] / cf[name][ok] - 1)
        # round to nearest with 11 significant bits: at most 2^-11 relative (plus float32's own 2^-24)
        assert rel.max() <= 2.0**-11 * (1 + 1e-6)
        assert rel.max() > 0  # it did round: the file is not a float file in disguise
    # a float EXR is not current for a half run: redone, not skipped
    proc = run_cli("apply", profile_path, photo, "-o", tmp_path / "float", "--precision", "half", "--jobs", "1")
    assert proc.returncode == 0 and "1 written, 0 already done" in proc.stdout, proc.stdout + proc.stderr
    assert _pixel_type(f) == "half"
    bad = run_cli("apply", profile_path, photo, "-o", tmp_path / "x", "--precision", "double")
    assert_one_line_error(bad, "--precision")




def _compression(path) -> str:
    return _spec(path)[1]


def test_compression_option_is_written_and_resumed(tmp_path, camera, profile_path):
    photo = _write_photo(camera, tmp_path, "c.dng", 4)
    out = tmp_path / "out"
    proc = run_cli("apply", profile_path, photo, "-o", out, "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    exr = out / "c.dng.exr"
    assert _compression(exr) == "none"  # the default (docs/apply.md: the measured choice)
    assert _pixel_type(exr) == "float"
    default, _ = read_exr(exr)
    # another compression is other settings: the EXR is redone, not skipped
    proc = run_cli("apply", profile_path, photo, "-o", out, "--compression", "piz", "--jobs", "1")
    assert proc.returncode == 0 and "1 written, 0 already done" in proc.stdout, proc.stdout + proc.stderr
    assert _compression(exr) == "piz"
    piz, _ = read_exr(exr)
    for name in default:  # both lossless: the same values
        assert np.array_equal(default[name], piz[name], equal_nan=True), name
    # the same compression again: skipped from the header
    proc = run_cli("apply", profile_path, photo, "-o", out, "--compression", "piz", "--jobs", "1")
    assert proc.returncode == 0 and "0 written, 1 already done" in proc.stdout, proc.stdout + proc.stderr
    bad = run_cli("apply", profile_path, photo, "-o", tmp_path / "x", "--compression", "jpeg")
    assert_one_line_error(bad, "--compression")


def test_mixed_precision_is_written_read_and_resumed(tmp_path, camera, profile_path):
    """``--precision mixed``: R, G, B, L663 as float32 (the same values as ``float``), the 1σ channels in half when
    they fit its normal range, else float32 with the header saying why; a rerun skips it, ``float`` redoes it."""
    photo = _write_photo(camera, tmp_path, "m.dng", 5)
    _apply_each(tmp_path, profile_path, photo, ("float", "mixed"))
    f, m = tmp_path / "float" / "m.dng.exr", tmp_path / "mixed" / "m.dng.exr"
    cf, _ = read_exr(f)
    cm, _ = read_exr(m)
    head = read_exr_header(m)
    for name in ("R", "G", "B", "L663"):
        assert np.array_equal(cf[name], cm[name], equal_nan=True), name  # radiance stays float32, lossless
    sigmas = [n for n in cf if n.endswith("_unc")]
    if head["uncertainty_precision"] == "half":
        assert head["exr_pixel_type"] == "mixed"
        for name in sigmas:
            ok = np.isfinite(cf[name]) & (cf[name] > 0)
            assert np.abs(cm[name][ok] / cf[name][ok] - 1).max() <= 2.0**-11 * (1 + 1e-6), name
    else:  # this photo's σ in W m⁻² sr⁻¹ nm⁻¹ fell outside half's normal range: kept as float32
        assert head["exr_pixel_type"] == "float" and "normal range" in head["uncertainty_precision"]
        for name in sigmas:
            assert np.array_equal(cf[name], cm[name], equal_nan=True), name
    proc = run_cli("apply", profile_path, photo, "-o", tmp_path / "mixed", "--precision", "mixed", "--jobs", "1")
    assert proc.returncode == 0 and "0 written, 1 already done" in proc.stdout, proc.stdout + proc.stderr
    proc = run_cli("apply", profile_path, photo, "-o", tmp_path / "mixed", "--jobs", "1")  # the default: float
    assert proc.returncode == 0 and "1 written, 0 already done" in proc.stdout, proc.stdout + proc.stderr
