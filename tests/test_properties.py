"""Property-based tests (hypothesis): parsers and loaders never fail except with a one-line CamcalError;
the numerical inverters never raise for finite input and mark impossible input NaN with a reason.

- manifest/CSV parser (:func:`camcal.io.manifest.read_manifest`): arbitrary bytes, and CSVs assembled from
  valid and invalid cells with any BOM / line ending / padding; accepted values obey the documented rules;
  valid records round-trip exactly.
- profile loader (:func:`camcal.io.container.read_container`, :func:`camcal.models.profile.load_profile`): a valid
  profile with mutated bytes, and with a mutated JSON document re-hashed (so the schema and the stage
  decoders, not the hash, must catch it); a profile that loads must also render its contract
  (what ``camcal profile show`` prints).
- inverters (:mod:`camcal.water.invert`, read-only use): any finite ratio, depth and σ.
"""

from __future__ import annotations

import csv
import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from camcal.errors import CamcalError
from camcal.io.container import JSON_MEMBER, MAPS_MEMBER, content_hash, read_container
from camcal.io.manifest import NUMERIC_COLUMNS, PLAUSIBLE_RANGE, POSITIVE_COLUMNS, TINY, read_manifest
from camcal.models.profile import contract, load_profile
from camcal.water.invert import Reason, invert_images, invert_ratio, tau_newton
from camcal.water.models import RefinedModel, SeedModel

FIXTURE_OK = settings(deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                            HealthCheck.too_slow])


def one_line(exc: CamcalError) -> None:
    assert "\n" not in str(exc) and str(exc).strip(), repr(str(exc))


# ---- manifest / CSV ---------------------------------------------------------------------------------------------

COLUMNS = ["file", *NUMERIC_COLUMNS, "note"]
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
cells = st.one_of(
    finite.map(repr), st.integers(-10**6, 10**6).map(str),
    st.sampled_from(["", "nan", "NaN", "inf", "-inf", "1e400", "abc", "0", "-0", " 1.5 ", "1,5", '"q"', "0x1",
                     "１", "1_0", "\x00", "../x.dng", "/abs.dng", "a/b.dng", "é.dng"]),
    st.text(max_size=8),
)


@st.composite
def manifest_texts(draw) -> str:
    header = draw(st.lists(st.sampled_from(COLUMNS), min_size=1, max_size=6))
    rows = draw(st.lists(st.lists(cells, min_size=len(header) - 1, max_size=len(header) + 1), max_size=5))
    nl = draw(st.sampled_from(["\n", "\r\n", "\r"]))
    text = nl.join(",".join(r) for r in [header, *rows]) + draw(st.sampled_from(["", nl]))
    return draw(st.sampled_from(["", "\ufeff"])) + text


def check_manifest(path: Path) -> None:
    try:
        rows = read_manifest(path)
    except CamcalError as exc:
        one_line(exc)
        return
    for name, rec in rows.items():
        assert name == rec["file"] and name and not Path(name).is_absolute() and ".." not in Path(name).parts
        for col, value in rec.items():
            if col in NUMERIC_COLUMNS and value is not None:
                assert isinstance(value, float) and math.isfinite(value)
                lo, hi = PLAUSIBLE_RANGE[col]
                assert lo <= value <= hi and (value == 0 or abs(value) >= TINY)
                if col in POSITIVE_COLUMNS:
                    assert value > 0


@settings(max_examples=200, deadline=None)
@given(st.binary(max_size=400))
def test_manifest_any_bytes(tmp_path_factory, data):
    p = tmp_path_factory.mktemp("m") / "frames.csv"
    p.write_bytes(data)
    check_manifest(p)


@settings(max_examples=200, deadline=None)
@given(manifest_texts())
def test_manifest_assembled_csv(tmp_path_factory, text):
    p = tmp_path_factory.mktemp("m") / "frames.csv"
    p.write_bytes(text.encode("utf-8", "surrogatepass"))
    check_manifest(p)


def in_range(col: str):
    lo, hi = PLAUSIBLE_RANGE[col]
    lo = max(lo, TINY if col in POSITIVE_COLUMNS or lo > 0 else lo)
    return st.floats(min_value=lo, max_value=hi, allow_nan=False).filter(lambda v: v == 0 or abs(v) >= TINY)


@settings(max_examples=80, deadline=None)
@given(st.data())
def test_manifest_valid_records_round_trip(tmp_path_factory, data):
    """Valid records survive any of BOM, CRLF, padding and column order exactly (repr of a float round-trips)."""
    cols = data.draw(st.lists(st.sampled_from(sorted(NUMERIC_COLUMNS)), unique=True, max_size=4))
    names = data.draw(st.lists(st.from_regex(r"[A-Za-z0-9_]{1,12}\.dng", fullmatch=True), unique=True, min_size=1,
                               max_size=5))
    records = [{"file": n, **{c: data.draw(in_range(c)) for c in cols}} for n in names]
    header = data.draw(st.permutations(["file", *cols]))
    pad = data.draw(st.sampled_from(["", " ", "  "]))
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator=data.draw(st.sampled_from(["\n", "\r\n"])))
    w.writerow(header)
    for rec in records:
        w.writerow([f"{pad}{rec[h]!r}{pad}" if h != "file" else rec[h] for h in header])
    p = tmp_path_factory.mktemp("m") / "frames.csv"
    p.write_bytes(data.draw(st.sampled_from([b"", b"\xef\xbb\xbf"])) + buf.getvalue().encode())
    rows = read_manifest(p)
    assert list(rows) == names
    for rec in records:
        for c in cols:
            assert rows[rec["file"]][c] == rec[c]


# ---- profile loader ---------------------------------------------------------------------------------------------


class Parts(tuple):
    """(container bytes, profile.json document, maps.exr bytes), with a short repr for hypothesis reports."""

    def __repr__(self) -> str:
        return "<valid profile>"


@pytest.fixture(scope="module")
def valid_profile(tmp_path_factory) -> Parts:
    from camcal.calibrate.run import CalibrateOptions, calibrate_session
    from camcal.models.profile import save_profile
    from camcal.synth.camera import SensorParams, SyntheticCamera
    from camcal.synth.session import SessionPlan, write_session

    root = tmp_path_factory.mktemp("prop-profile")
    cam = SyntheticCamera(SensorParams(width=96, height=64))
    session = write_session(root / "S", cam, SessionPlan(n_bias=3, n_dark=2, dark_exposures_s=(2.0, 16.0), n_flat=3,
                                                         linearity_steps=9, sweep_step_nm=50.0, n_sweep=1))
    profile, _ = calibrate_session(session, CalibrateOptions(jobs=1))
    save_profile(profile, root / "p.camcal")
    data = (root / "p.camcal").read_bytes()
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        return Parts((data, json.loads(zf.read(JSON_MEMBER)), zf.read(MAPS_MEMBER)))


def load_bytes(path: Path, data: bytes) -> None:
    path.write_bytes(data)
    try:
        read_container(path)
        prof = load_profile(path)
    except CamcalError as exc:
        one_line(exc)
        return
    json.dumps(contract(prof), allow_nan=False)  # what `camcal profile show --json` prints


@settings(FIXTURE_OK, max_examples=100)
@given(st.data())
def test_profile_mutated_bytes(valid_profile, tmp_path, data):
    raw = bytearray(valid_profile[0])
    n = data.draw(st.integers(1, 8))
    for _ in range(n):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.one_of(st.none(), st.integers(0, len(raw))))
    load_bytes(tmp_path / "p.camcal", bytes(raw[:cut] if cut is not None else raw))


json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-2**70, 2**70), finite, st.text(max_size=6)),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner, max_size=4),
    max_leaves=12,
)


def _paths(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, (*prefix, k))
    elif isinstance(node, list) and node:
        yield from _paths(node[0], (*prefix, 0))
        yield from _paths(node[-1], (*prefix, len(node) - 1))


def rezip(doc: dict, maps: bytes) -> bytes:
    doc = json.loads(json.dumps(doc))
    if isinstance(doc.get("integrity"), dict):
        doc["integrity"]["content_sha256"] = content_hash(doc)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr(JSON_MEMBER, json.dumps(doc))
        zf.writestr(MAPS_MEMBER, maps)
    return buf.getvalue()


@settings(FIXTURE_OK, max_examples=80)
@given(st.data())
def test_profile_mutated_json_rehashed(valid_profile, tmp_path, data):
    _, doc, maps = valid_profile
    paths = [p for p in _paths(doc) if p and p[0] != "integrity"]
    path = data.draw(st.sampled_from(paths))
    action = data.draw(st.sampled_from(["replace", "delete", "add"]))
    new = json.loads(json.dumps(doc))
    node = new
    for k in path[:-1]:
        node = node[k]
    if action == "delete":
        del node[path[-1]]
    elif action == "add" and isinstance(node, dict):
        node[data.draw(st.text(min_size=1, max_size=6))] = data.draw(json_values)
    else:
        node[path[-1]] = data.draw(json_values)
    load_bytes(tmp_path / "p.camcal", rezip(new, maps))


@pytest.mark.parametrize("field,value", [("saturated", True), ("files", "a.dng"), ("used", [1, 0]),
                                         ("mean_dn", ["x"])])
def test_profile_response_points_of_the_wrong_type_are_refused(valid_profile, tmp_path, field, value):
    """The response's points are read back (the report's saturated files, the plots): a field of the wrong type
    under a valid hash is refused by the schema in one line, not an internal error (the mutation above found
    ``"saturated": true`` in CI, 2026-12-03)."""
    _, doc, maps = valid_profile
    new = json.loads(json.dumps(doc))
    points = next(m["points"] for m in new["response"].values() if m and m.get("points"))
    points[next(iter(points))][field] = value
    path = tmp_path / "p.camcal"
    path.write_bytes(rezip(new, maps))
    with pytest.raises(CamcalError, match="points"):
        load_profile(path)


def test_profile_unmutated_loads(valid_profile, tmp_path):
    """The control: the valid profile (and its re-zipped copy) load, so the mutations above test the damage."""
    data, doc, maps = valid_profile
    (tmp_path / "a.camcal").write_bytes(data)
    (tmp_path / "b.camcal").write_bytes(rezip(doc, maps))
    assert contract(load_profile(tmp_path / "a.camcal")) == contract(load_profile(tmp_path / "b.camcal"))


# ---- inverters (camcal.water, read-only) ------------------------------------------------------------------------

MODELS = (SeedModel(), RefinedModel(), RefinedModel(view_angle_rad=0.4, background_absorption_per_m=0.3))
any_finite = st.floats(allow_nan=False, allow_infinity=False)


def check_inversion(inv, ratio, depth) -> None:
    r = np.broadcast_to(np.asarray(ratio, float), inv.reason.shape)
    d = np.broadcast_to(np.asarray(depth, float), inv.reason.shape)
    assert set(np.unique(inv.reason).tolist()) <= {int(x) for x in Reason}
    bad = inv.reason != 0
    assert np.isnan(inv.c_mol_per_L[bad]).all() and np.isnan(inv.c_ug_per_L[bad]).all()
    assert np.isfinite(inv.c_mol_per_L[~bad]).all() and (inv.c_mol_per_L[~bad] >= 0).all()
    assert ((r <= 0) <= (inv.reason == Reason.NOT_POSITIVE)).all()
    assert (((d <= 0) & (r > 0) & (inv.reason != Reason.ABOVE_CLEAR_WATER) & (inv.reason != Reason.TOO_DARK))
            <= (inv.reason == Reason.BAD_DEPTH)).all()


@settings(max_examples=150, deadline=None)
@given(st.lists(any_finite, min_size=1, max_size=12), st.one_of(any_finite, st.lists(any_finite, min_size=1,
                                                                                      max_size=1)),
       st.one_of(st.none(), st.floats(min_value=0, max_value=1e6)), st.sampled_from(["table", "newton"]),
       st.sampled_from(range(len(MODELS))))
def test_invert_ratio_any_finite_input(ratio, depth, sigma, method, k):
    """No exception for any finite ratio, depth (also ≤ 0 or huge) and σ; NaN exactly where a reason is given."""
    depth = np.asarray(depth, float)
    inv = invert_ratio(np.asarray(ratio), MODELS[k], depth, sigma_ln_ratio=sigma, method=method)
    check_inversion(inv, ratio, depth)
    tau, why = tau_newton(np.asarray(ratio), MODELS[k].closed_form())
    assert np.isnan(tau[why != 0]).all() and (tau[why == 0] >= 0).all()


@settings(max_examples=100, deadline=None)
@given(st.floats(min_value=0, max_value=2e-6), st.floats(min_value=0.05, max_value=1.0),
       st.sampled_from(range(len(MODELS))))
def test_invert_ratio_round_trip(c_mol_per_L, depth_m, k):
    """Possible ratios invert to their concentration (both routes); relative 1e-7, absolute 1e-15 mol/L
    (the table interpolates to 1e-11 relative in τ; C = (τ − τ_bg)/per-C loses digits only near C = 0)."""
    m = MODELS[k]
    r = np.atleast_1d(m.ratio(c_mol_per_L, depth_m))
    assume(np.isfinite(r).all() and (r > 1e-250).all())
    for method in ("table", "newton"):
        inv = invert_ratio(r, m, depth_m, method=method)
        assert inv.reason[0] in (Reason.OK, Reason.TOO_DARK)
        if inv.reason[0] == Reason.OK:
            assert inv.c_mol_per_L[0] == pytest.approx(c_mol_per_L, rel=1e-7, abs=1e-15)


@settings(max_examples=100, deadline=None)
@given(st.lists(any_finite, min_size=4, max_size=4), st.one_of(any_finite, st.lists(any_finite, min_size=4,
                                                                                     max_size=4)),
       st.floats(min_value=1e-4, max_value=50.0))
def test_invert_images_any_finite_input(sub, ref, depth):
    sub_a = np.asarray(sub, float).reshape(2, 2)
    ref_a = np.asarray(ref, float).reshape(2, 2) if isinstance(ref, list) else float(ref)
    inv = invert_images(sub_a, ref_a, SeedModel(), depth, sigma_submerged=0.01 * np.abs(sub_a),
                        sigma_reference=0.01)
    bad = inv.reason != 0
    assert np.isnan(inv.c_mol_per_L[bad]).all() and np.isfinite(inv.c_mol_per_L[~bad]).all()
    ref_b = np.broadcast_to(np.asarray(ref_a, float), (2, 2))
    assert ((ref_b <= 0) <= (inv.reason == Reason.BAD_REFERENCE)).all()
