"""A profile written by an earlier camcal loads and applies to the same numbers (bit for bit).

``tests/data/stored.camcal`` (schema 1.3), ``stored_photo.dng`` and ``stored_expected.npz`` were written by
``tests/data/make_stored_profile.py`` before the structure rework of issue 17; the files are ours (synthetic).
``L663`` and ``L663_unc`` were recorded again when L663 became the spectral radiance at 663 nm (W m⁻² sr⁻¹ nm⁻¹,
from the best estimator the profile supports, issue 45; before, the default estimator wrote an in-band
quantity under that name); R, G and B are the numbers stored at first, bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from camcal.apply.photo import apply
from camcal.io.read import load_frame
from camcal.models.profile import contract, load_profile
from tests.conftest import run_cli

DATA = Path(__file__).resolve().parents[1] / "data"


def test_stored_profile_loads_and_applies_identically():
    profile = load_profile(DATA / "stored.camcal")
    assert profile.schema_version == "1.3"
    assert contract(profile)["camera"]["layout"] == "bayer"
    image = apply(load_frame(DATA / "stored_photo.dng"), profile)
    with np.load(DATA / "stored_expected.npz", allow_pickle=False) as expected:
        # every channel written when the file was stored comes out bit-identical; channels added since (the
        # per-band 1σ maps R_unc, G_unc, B_unc) are new outputs, not changes of the old ones
        added = set(image.channels) - set(expected.files)
        assert set(expected.files) <= set(image.channels) and added <= {"R_unc", "G_unc", "B_unc"}, added
        for name in expected.files:
            np.testing.assert_array_equal(image.channels[name], expected[name], err_msg=name)
        # a meaningful photo: radiance everywhere but at the few defective pixels
        assert np.isfinite(expected["G"]).mean() > 0.99 and np.nanmedian(expected["G"]) > 0


def test_stored_profile_through_the_cli(tmp_path):
    proc = run_cli("apply", DATA / "stored.camcal", DATA / "stored_photo.dng", "-o", tmp_path)
    assert proc.returncode == 0, proc.stderr
    from camcal.io.exr import read_exr

    channels, _ = read_exr(tmp_path / "stored_photo.dng.exr")
    with np.load(DATA / "stored_expected.npz", allow_pickle=False) as expected:
        for name in expected.files:
            np.testing.assert_array_equal(channels[name], expected[name], err_msg=name)


@pytest.mark.parametrize("name", ["stored.camcal", "stored_photo.dng", "stored_expected.npz"])
def test_stored_files_are_small(name):
    assert (DATA / name).stat().st_size < 200_000
