"""``camcal water forward|invert|simulate``: the rendering equation and chlorophyll-a inversion."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from camcal.apply.provenance import check_made_by, check_pair
from camcal.cli.common import console, print_json, progress
from camcal.cli.water_tables import forward_table, ratio_table, summary_table
from camcal.errors import CamcalError
from camcal.io.exr import read_exr, write_exr
from camcal.models.profile import load_profile
from camcal.region import Region, pixels_per_output_cell
from camcal.water.band import band_model_from_profile, read_chlorophyll_csv
from camcal.water.invert import Reason, invert_images, invert_ratio
from camcal.water.lampfield import PixelGeometry
from camcal.water.models import SEED_CUTOFF_RAD, LampModel, RefinedModel, SeedModel
from camcal.water.simulate import simulate_seed_section5
from camcal.water.uncertainty import Uncertain, all_terms, combine, dominant
from camcal.water.units import (
    mol_per_L_to_ug_per_L,
    parse_concentration_mol_per_L,
    parse_epsilon_L_per_mol_cm,
    parse_length_m,
)


def _model(kind: str, epsilon: str, albedo: float, cutoff_deg: float | None, view_deg: float, n_water: float,
           water_absorption: float, background_absorption: float, reflectance: str, transmittance: str = "mean",
           lamp_height: str | None = None, lamp_angle_deg: float | None = None):

    eps = parse_epsilon_L_per_mol_cm(epsilon)
    if not (eps > 0 and 0 < albedo < np.inf):
        raise CamcalError("epsilon and albedo must be positive (and finite)")
    if reflectance not in ("fresnel", "schlick"):
        raise CamcalError(f"unknown reflectance {reflectance!r}; use fresnel or schlick")
    if transmittance not in ("mean", "exact"):
        raise CamcalError(f"unknown --transmittance {transmittance!r}; use mean or exact")
    if kind in ("seed", "seed-first-order"):
        cut = SEED_CUTOFF_RAD if cutoff_deg is None else np.radians(cutoff_deg)
        if not 0 < cut < np.pi / 2:
            raise CamcalError("cutoff angle must be between 0 and 90 degrees")
        return SeedModel(eps, albedo, float(cut))
    if kind not in ("refined", "lamp"):
        raise CamcalError(f"unknown --water-model {kind!r}; use refined, lamp, seed or "
                          "seed-first-order")
    if not 0 <= view_deg < 90:
        raise CamcalError(f"--view-deg must be from 0 to below 90 degrees (from nadir), got {view_deg!r}")
    if not 1 <= n_water < 3:
        raise CamcalError(f"--n-water must be a refractive index from 1 to 3 (water: 1.33), got {n_water!r}")
    for name, value in (("--water-absorption", water_absorption), ("--background-absorption",
                                                                    background_absorption)):
        if not 0 <= value < np.inf:
            raise CamcalError(f"{name} must be a finite absorption >= 0 per m, got {value!r}")
    if kind == "lamp":
        if lamp_height is None or lamp_angle_deg is None:
            raise CamcalError("--water-model lamp needs --lamp-height (above the water surface, e.g. 1m) and "
                              "--lamp-angle (degrees from the vertical in air)")
        h = parse_length_m(lamp_height)
        if not 0.01 <= h <= 100:
            raise CamcalError(f"--lamp-height {lamp_height!r} is implausible: give 1 cm to 100 m")
        if not 0 <= lamp_angle_deg < 85:
            raise CamcalError(f"--lamp-angle must be from 0 to below 85 degrees, got {lamp_angle_deg!r}")
        return LampModel(h, float(np.radians(lamp_angle_deg)), eps, albedo, n_water, float(np.radians(view_deg)),
                         water_absorption, background_absorption, reflectance)
    cut = np.pi / 2 if cutoff_deg is None else np.radians(cutoff_deg)
    if not 0 < cut <= np.pi / 2:
        raise CamcalError("cutoff angle must be above 0 and at most 90 degrees")
    return RefinedModel(eps, albedo, n_water, float(cut), float(np.radians(view_deg)), water_absorption,
                        background_absorption, reflectance, transmittance)


#: Plausible disk depths, m: a micrometre to the deepest ocean (anything else is a typing error).
DEPTH_RANGE_M = (1e-6, 1.1e4)
#: Largest plausible chlorophyll-a concentration, mol/L (≈ 0.9 kg/L: denser than any pigment solution).
MAX_CONCENTRATION_MOL_PER_L = 1.0


def _list(text: str, parse, what: str) -> np.ndarray:
    values = np.array([parse(t) for t in text.split(",") if t.strip()], dtype=float)
    if values.size == 0:
        raise CamcalError(f"--{what} needs at least one value, got {text!r}")
    return values


def _depth(text: str) -> float:
    """A disk depth in metres: with its unit, positive and plausible (:data:`DEPTH_RANGE_M`), else CamcalError.
    A bare number is refused: metres, centimetres and millimetres are all in use at the water's edge."""

    t = str(text).strip()
    try:
        bare = np.isfinite(float(t))
    except ValueError:
        bare = False
    if bare:
        raise CamcalError(f"--depth {t} has no unit: give it with one, e.g. {t}m, {t}cm or {t}mm (accepted units: "
                          "m, cm, mm)")
    d = parse_length_m(text)
    if not d > 0:
        raise CamcalError(f"depth must be positive, got {text!r}")
    if not DEPTH_RANGE_M[0] <= d <= DEPTH_RANGE_M[1]:
        raise CamcalError(f"depth {text!r} is implausible: give {DEPTH_RANGE_M[0]:g} m to {DEPTH_RANGE_M[1]:g} m")
    return d


def _ratio(text: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise CamcalError(f"--ratio must be a comma list of numbers, got {text.strip()!r}") from None


def _json_list(values) -> list:
    """Floats for JSON: non-finite values become null (JSON has no NaN)."""
    return [float(v) if np.isfinite(v) else None for v in np.asarray(values, dtype=float).ravel()]


def _json_nested(values) -> list:
    a = np.asarray(values, dtype=float)
    return np.where(np.isfinite(a), a, None).tolist()


def _split_unc(text: str) -> tuple[str, str | None]:
    """'0.30m±0.005m' (or '+-') → ('0.30m', '0.005m'); no ± → (text, None)."""
    for sep in ("±", "+/-", "+-"):
        if sep in text:
            a, b = text.split(sep, 1)
            return a.strip(), b.strip()
    return text.strip(), None


def _unc_value(value: float, text: str | None, parse, what: str) -> float:
    """A 1-σ from '0.005m', '2%' (of the value) or None (0)."""
    if text is None:
        return 0.0
    if text.endswith("%"):
        try:
            sig = abs(value) * float(text[:-1]) / 100.0
        except ValueError:
            raise CamcalError(f"cannot read the uncertainty {text!r} of {what}") from None
    else:
        sig = parse(text)
    if not (np.isfinite(sig) and sig >= 0):
        raise CamcalError(f"the uncertainty of {what} must be a finite number >= 0, got {text!r}")
    return float(sig)


def _number(what: str):
    def parse(text: str) -> float:
        try:
            return float(text)
        except ValueError:
            raise CamcalError(f"cannot read {what} {text!r}: give a number or a percentage") from None
    return parse


def _angle_deg(text: str) -> float:
    t = text.strip().lower().removesuffix("deg").removesuffix("°").strip()
    try:
        return float(t)
    except ValueError:
        raise CamcalError(f"cannot read the angle {text!r}: give degrees, e.g. 20 or 20±0.5") from None


def _depth_unc(text: str) -> tuple[float, float]:

    a, b = _split_unc(text)
    d = _depth(a)
    return d, _unc_value(d, b, parse_length_m, "--depth")


def _build(kind, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption, background_absorption,
           reflectance, transmittance, lamp_height, lamp_angle, epsilon_unc):
    """(model, stated inputs other than depth) from the options."""

    inputs = []
    h_text = a_deg = None
    if lamp_height is not None:
        h_text, h_unc = _split_unc(lamp_height)
        h_sig = _unc_value(parse_length_m(h_text), h_unc, parse_length_m, "--lamp-height")
    if lamp_angle is not None:
        a_text, a_unc = _split_unc(lamp_angle)
        a_deg = _angle_deg(a_text)
        a_sig = _unc_value(a_deg, a_unc, _angle_deg, "--lamp-angle")
    m = _model(kind, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption, background_absorption,
               reflectance, transmittance, h_text, a_deg)
    if kind == "lamp":
        inputs += [Uncertain("lamp_height", m.height_m, h_sig, "m"), Uncertain("lamp_angle", a_deg, a_sig, "deg")]
    if epsilon_unc is not None:  # '3%' or a fraction '0.03'
        inputs.append(Uncertain("epsilon", 1.0, _unc_value(1.0, epsilon_unc.strip(), _number("--epsilon-unc"),
                                                           "--epsilon-unc"), "relative"))
    return m, inputs


def _band(m, profile, band_channel, illuminant, chlorophyll_csv, background_absorption, meta):
    """Wrap a geometry in the band model of a profile's channel (illuminant: the lamp for --model lamp)."""

    light = illuminant or ("lamp" if getattr(m, "name", "") == "lamp" else "D65")
    chl = read_chlorophyll_csv(chlorophyll_csv) if chlorophyll_csv else None
    band = band_model_from_profile(profile, band_channel, geometry=m, chlorophyll=chl, illuminant=light,
                                   background_absorption_per_m=background_absorption)
    meta.update({"inversion": "band", "profile": str(profile), "band_channel": band_channel,
                 "illuminant": light, "band_model": band.describe()})
    return band


def _pixel_geometry(model: str, size: str, centre: str | None, direction_deg: float, per_cell: int = 1):
    """The per-pixel lamp geometry on the EXR's grid from options in photo pixels.

    ``--disk-pixel-size`` is one photo pixel's size on the disk plane and ``--disk-centre-px`` the disk centre in
    photo pixels (full resolution, as every pixel option); an EXR cell holds ``per_cell`` × ``per_cell`` photo
    pixels, its centre at photo coordinate per_cell·i + (per_cell − 1)/2.
    """

    if model != "lamp":
        raise CamcalError("--disk-pixel-size (per-pixel geometry) is for --water-model lamp")
    if not centre:
        raise CamcalError("--disk-pixel-size needs --disk-centre-px x,y (the disk centre in photo pixels)")
    try:
        cx, cy = (float(v) for v in centre.split(","))
    except ValueError:
        raise CamcalError(f"--disk-centre-px must be x,y in pixels, got {centre!r}") from None
    if not (np.isfinite(direction_deg) and np.isfinite(cx) and np.isfinite(cy)):
        raise CamcalError("--disk-centre-px and --lamp-direction must be finite numbers")
    k = float(per_cell)
    return PixelGeometry(parse_length_m(size) * k, ((cx - (k - 1) / 2) / k, (cy - (k - 1) / 2) / k),
                         float(direction_deg))


def _unc_summary(terms: dict, inputs: list) -> dict:
    """Median of each σ_C term, the dominant one, and the inputs whose uncertainty was not stated.

    Without the ratio's noise (``--relative-sigma`` or ``--sigma-channel``) there is no total: the stated
    terms alone (often only the profile's c(λ)) would read like a measured σ_C. The summary then says
    ``"total": null`` and lists what is missing.
    """

    out = dominant(terms)
    missing = [q.name for q in inputs if not q.sigma > 0] + ([] if "ratio" in terms else ["ratio"])
    if missing:
        out["not_stated"] = missing  # these contribute nothing to σ_C: state them to include them
    if "ratio" not in terms:
        out["total"] = None
        out["dominant"] = None
        out["note"] = ("no total σ_C: the ratio's noise is not stated (give --relative-sigma, e.g. 1.5% or 0.015, "
                       "or --sigma-channel R_unc)")
    return out


def _print_unc_note(unc: dict) -> None:
    """The σ_C caveats of a ratio table: inputs whose uncertainty was not stated, and why there is no total."""
    if unc.get("not_stated"):
        console.print(f"not stated (no σ): {', '.join(unc['not_stated'])}", markup=False, highlight=False)
    if unc.get("note"):
        console.print(f"note: {unc['note']}", markup=False, highlight=False)


def _total(terms: dict, inv) -> np.ndarray:
    """σ_C per pixel from the terms; NaN (not stated) when the ratio's noise is not among them."""
    if "ratio" not in terms:
        return np.full(np.shape(inv.c_ug_per_L), np.nan)
    return combine(terms) if terms else inv.sigma_ug_per_L


def _none_valid(reasons: dict, roi: str | None, where: Path | None = None) -> CamcalError:
    """The error for an inversion where no pixel (or no ratio) gave a concentration, reasons counted."""
    counts = ", ".join(f"{k} {v}" for k, v in sorted(reasons.items(), key=lambda kv: -kv[1]))
    hint = ""
    if roi and reasons.get("outside_roi"):
        hint = f"; check --roi {roi} (x,y,w,h in photo pixels at full resolution) covers the disk"
    elif reasons.get("above_clear_water"):
        hint = "; the ratio is brighter than clear water allows: check the depth, the --water-model and the images"
    return CamcalError(f"no valid concentration: {counts}{hint}", where)


def _fraction(text: str | None, what: str) -> float | None:
    """A relative amount given as '1.5%' or as the fraction '0.015' (None stays None)."""
    if text is None:
        return None
    t = text.strip()
    try:
        value = float(t[:-1]) / 100.0 if t.endswith("%") else float(t)
    except ValueError:
        raise CamcalError(f"cannot read {what} {text!r}: give a percentage (1.5%) or a fraction (0.015)") from None
    if not (np.isfinite(value) and value >= 0):
        raise CamcalError(f"{what} must be a finite number >= 0, got {text!r}")
    return value


def register(app: typer.Typer) -> None:
    water = typer.Typer(help="Rendering equation in a water column; chlorophyll-a inversion.", no_args_is_help=True)
    app.add_typer(water, name="water")

    common = dict(
        model=typer.Option("refined", "--water-model", help="Water physics: refined (default: Fresnel surface, "
                           "water absorption; the model for real photos), lamp (seed §4: point lamp over a tank), "
                           "seed (eq. 10 exact: the seed's idealisation, no water, no surface; for its figures), "
                           "seed-first-order (eq. 11). Old spelling: --model."),
        epsilon=typer.Option("seed", help="ε: '88L/g/cm', '78628L/mol/cm', or seed|porra1989|jeffrey-humphrey1975."),
        albedo=typer.Option(1.0, help="Disk albedo relative to the reference."),
        cutoff_deg=typer.Option(None, help="Cutoff angle θc, degrees (seed: π/2.1; refined: air-side sky cutoff)."),
        view_deg=typer.Option(0.0, help="refined/lamp: camera view angle from nadir in air, degrees."),
        n_water=typer.Option(1.33, help="refined/lamp: refractive index of water."),
        water_absorption=typer.Option(0.425, help="refined/lamp, narrowband: pure-water absorption, m⁻¹ "
                                       "(Pope & Fry 1997 at 663 nm; --profile uses their full spectrum)."),
        background_absorption=typer.Option(0.0, help="refined/lamp: background (CDOM) absorption, m⁻¹."),
        reflectance=typer.Option("fresnel", help="refined/lamp: fresnel (exact) or schlick."),
        transmittance=typer.Option("mean", help="refined: mean (T̄, E₃ closed form) or exact (T(θ) inside the "
                                   "integral, quadrature)."),
        lamp_height=typer.Option(None, help="lamp: height above the water surface, e.g. '1m' or '1m±0.01m'."),
        lamp_angle=typer.Option(None, help="lamp: air zenith angle of its ray to the disk centre, degrees, "
                                "e.g. '20' or '20±0.5'."),
        epsilon_unc=typer.Option(None, help="Relative 1-σ of ε (or of the absorber spectrum with --profile): "
                                 "'3%' or the fraction '0.03'."),
        profile=typer.Option(None, "--profile", help="Calibration profile: band-aware model over its c(λ) "
                             "(images hold band radiances, as `camcal apply` writes)."),
        band_channel=typer.Option("R", help="With --profile: the channel whose c(λ) defines the band."),
        illuminant=typer.Option(None, help="With --profile: the light (default D65; lamp model: 'lamp' = 3200 K "
                                "black body); flat, A, 3000K, ... or a measured lamp CSV (wavelength_nm,value)."),
        chlorophyll_csv=typer.Option(None, "--absorber-csv", "--chlorophyll-csv", help="With --profile: the "
                                     "absorber's spectrum (chlorophyll, a dye): CSV of ε(λ) per gram or per mole, "
                                     "or a measured absorbance (default: Bricaud 1998 chlorophyll)."),
        as_json=typer.Option(False, "--json", help="Print the result as JSON (default: a table)."),
    )

    @water.command("forward")
    def forward_cmd(
        concentration: str = typer.Option(..., help="Comma list: '1e-7mol/L,2e-7mol/L' or '89ug/L'."),
        depth: str = typer.Option(..., help="Comma list: '10cm,20cm' or '0.2m'."),
        model: str = common["model"], epsilon: str = common["epsilon"], albedo: float = common["albedo"],
        cutoff_deg: float = common["cutoff_deg"], view_deg: float = common["view_deg"],
        n_water: float = common["n_water"], water_absorption: float = common["water_absorption"],
        background_absorption: float = common["background_absorption"], reflectance: str = common["reflectance"],
        transmittance: str = common["transmittance"], lamp_height: str = common["lamp_height"],
        lamp_angle: str = common["lamp_angle"], profile: Path = common["profile"],
        band_channel: str = common["band_channel"], illuminant: str = common["illuminant"],
        chlorophyll_csv: Path = common["chlorophyll_csv"], as_json: bool = common["as_json"],
    ) -> None:
        """Predicted ratio (disk radiance over reference) for each concentration and depth: a table (rows depth,
        columns concentration), or JSON with --json."""

        m, _ = _build(model, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption,
                      background_absorption, reflectance, transmittance, lamp_height, lamp_angle, None)
        c = _list(concentration, parse_concentration_mol_per_L, "concentration")
        d = _list(depth, _depth, "depth")
        if np.any(c < 0):
            raise CamcalError(f"concentrations must be >= 0, got {concentration!r}")
        if np.any(c > MAX_CONCENTRATION_MOL_PER_L):
            raise CamcalError(f"concentration {concentration!r} is implausible: at most "
                              f"{MAX_CONCENTRATION_MOL_PER_L:g} mol/L")
        meta = {"model": model, "inversion": "narrowband"}
        with np.errstate(all="ignore"):  # extreme optical depths: the ratio underflows to 0 (or NaN -> null)
            if profile is not None:
                band = _band(m, profile, band_channel, illuminant, chlorophyll_csv, background_absorption, meta)
                ratio = np.array([band.ratio(mol_per_L_to_ug_per_L(c), float(dd)) for dd in d])
            elif model == "seed-first-order":
                ratio = m.ratio_first_order(c[None, :], d[:, None])
            else:
                ratio = m.ratio(c[None, :], d[:, None])
        doc = {**meta, "depth_m": d.tolist(), "c_mol_per_L": c.tolist(),
               "c_ug_per_L": mol_per_L_to_ug_per_L(c).tolist(), "ratio": _json_nested(ratio)}
        if as_json:
            print_json(doc)
        else:
            console.print(forward_table(doc))

    @water.command("invert")
    def invert_cmd(
        depth: str = typer.Option(..., help="Disk depth: '0.2m', '20cm', or with its 1-σ: '0.30m±0.005m'."),
        submerged: Path = typer.Option(None, help="EXR with the submerged disk's radiance."),
        reference: Path = typer.Option(None, help="EXR with the reference radiance (same channel)."),
        channel: str = typer.Option(None, help="EXR channel to read from both files (default L663; R with --profile)."),
        sigma_channel: str = typer.Option(None, help="EXR channel with the 1-σ radiance uncertainty (both files)."),
        relative_sigma: str = typer.Option(None, help="Relative 1-σ uncertainty of the ratio (instead of maps): "
                                           "'1.5%' or the fraction '0.015'."),
        roi: str = typer.Option(None, "--roi", help="Region x,y,w,h in photo pixels at full resolution (rounded "
                                "outward to the EXR's grid: half resolution for Bayer photos, from the EXR's "
                                "'resolution' note; an EXR without one is taken at its own pixels); other "
                                "pixels become NaN."),
        ratio: str = typer.Option(None, help="Numbers only: comma list of ratios; prints a table (JSON with --json)."),
        out: Path = typer.Option(None, "-o", "--output", help="Output EXR (chl_ug_per_L, chl_unc_ug_per_L, the σ "
                                 "terms chl_unc_<term>_ug_per_L, reason)."),
        profile: Path = common["profile"], band_channel: str = common["band_channel"],
        illuminant: str = common["illuminant"], chlorophyll_csv: Path = common["chlorophyll_csv"],
        model: str = common["model"], epsilon: str = common["epsilon"], albedo: float = common["albedo"],
        cutoff_deg: float = common["cutoff_deg"], view_deg: float = common["view_deg"],
        n_water: float = common["n_water"], water_absorption: float = common["water_absorption"],
        background_absorption: float = common["background_absorption"], reflectance: str = common["reflectance"],
        transmittance: str = common["transmittance"], lamp_height: str = common["lamp_height"],
        lamp_angle: str = common["lamp_angle"], epsilon_unc: str = common["epsilon_unc"],
        disk_pixel_size: str = typer.Option(None, help="lamp, EXR: size of one photo pixel on the disk plane "
                                            "(e.g. '0.4mm'): invert each pixel with its own lamp geometry, not "
                                            "the disk centre's (needs --disk-centre-px)."),
        disk_centre_px: str = typer.Option(None, help="lamp, per pixel: the disk centre in photo pixels at full "
                                           "resolution, 'x,y'."),
        lamp_direction: float = typer.Option(180.0, help="lamp, per pixel: direction in the image from the disk "
                                             "centre toward the lamp, degrees from +x toward +y (180: left)."),
        as_json: bool = common["as_json"],
    ) -> None:
        """Chlorophyll-a (or dye) per pixel from a submerged and a reference radiance image (or from numbers).

        Narrowband by default (the images are radiances at the wavelength of --epsilon); with --profile,
        band-aware: the ratio is predicted by integrating the model over the profile's c(λ) of
        --band-channel with Pope & Fry (1997) water (refined and lamp models) and an absorber spectrum.
        σ_C carries the ratio noise, the stated ± of depth, lamp height and angle, --epsilon-unc and the
        profile's uncertainty of c(λ); the output names the dominant term.
        """

        d, d_sig = _depth_unc(depth)
        relative_sigma = _fraction(relative_sigma, "--relative-sigma")
        if model == "seed-first-order":
            raise CamcalError("invert uses the exact models: choose --water-model refined, lamp or seed")
        m, inputs = _build(model, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption,
                           background_absorption, reflectance, transmittance, lamp_height, lamp_angle, epsilon_unc)
        inputs = [Uncertain("depth", d, d_sig, "m"), *inputs]
        meta = {"model": model, "depth_m": d, "stated_uncertainties": {q.name: {"value": q.value, "sigma": q.sigma,
                                                                                 "unit": q.unit} for q in inputs}}
        if model == "refined":
            meta["transmittance"] = transmittance
        if profile is not None:
            m = _band(m, profile, band_channel, illuminant, chlorophyll_csv, background_absorption, meta)
            channel = channel or band_channel
        else:
            meta.update({"inversion": "narrowband", "epsilon_L_per_mol_cm": m.epsilon_L_per_mol_cm})
            channel = channel or "L663"
        if ratio is not None:
            if disk_pixel_size is not None:
                raise CamcalError("--disk-pixel-size needs images (--submerged/--reference), not --ratio")
            r = _list(ratio, _ratio, "ratio")
            if profile is not None:
                inv = m.inverse(d).concentration(r, sigma_ln_ratio=relative_sigma)
            else:
                inv = invert_ratio(r, m, d, sigma_ln_ratio=relative_sigma)
            terms = all_terms(inv, m, d, inputs)
            total = _total(terms, inv)
            doc = {**meta, "ratio": _json_list(r), "c_mol_per_L": _json_list(inv.c_mol_per_L),
                   "c_ug_per_L": _json_list(inv.c_ug_per_L), "sigma_ug_per_L": _json_list(total),
                   "sigma_terms_ug_per_L": {k: _json_list(v) for k, v in terms.items()},
                   "uncertainty": _unc_summary(terms, inputs),
                   "reason": [Reason(int(v)).name.lower() for v in inv.reason]}
            if as_json:
                print_json(doc)
            else:
                console.print(ratio_table(doc))
                _print_unc_note(doc["uncertainty"])
            return
        if submerged is None or reference is None or out is None:
            raise CamcalError("give --submerged A.exr --reference B.exr -o chl.exr, or --ratio for numbers")

        if sigma_channel and sigma_channel.endswith("_unc") and sigma_channel != f"{channel}_unc":
            raise CamcalError(f"--sigma-channel {sigma_channel} is not the uncertainty of channel {channel}: give "
                              f"{channel}_unc (camcal apply writes one per band: R_unc, G_unc, B_unc, L663_unc)")
        names = [channel] + ([sigma_channel] if sigma_channel else [])
        with progress() as bar:
            task = bar.add_task("inverting", total=3)
            sub, sub_meta = read_exr(submerged, names)
            ref, ref_meta = read_exr(reference, names)
            check_pair(sub_meta, submerged, ref_meta, reference)
            if profile is not None:
                prof = load_profile(profile)
                for meta_x, path_x in ((sub_meta, submerged), (ref_meta, reference)):
                    check_made_by(meta_x, path_x, prof, profile)
            (h, w), (rh, rw) = sub[channel].shape, ref[channel].shape
            if (h, w) != (rh, rw):
                raise CamcalError(f"is {w}x{h} pixels but the reference {reference.name} is {rw}x{rh}; the two images "
                                  "must have one size (same camera, same crop)", submerged)
            region = None
            per_cell = pixels_per_output_cell(sub_meta.get("resolution")) or 1
            if roi:
                ys, xs = Region.parse(roi).window((h, w), per_cell, submerged)
                region = (xs.start, ys.start, xs.stop - xs.start, ys.stop - ys.start)
                meta["roi"] = {"photo_pixels": roi, "exr_pixels_x_y_w_h": list(region),
                               "photo_pixels_per_exr_pixel": per_cell}
            bar.advance(task)
            kwargs = {}
            if sigma_channel:
                kwargs = {"sigma_submerged": sub[sigma_channel], "sigma_reference": ref[sigma_channel]}
            elif relative_sigma is not None:
                kwargs = {"sigma_submerged": relative_sigma * np.abs(sub[channel].astype(float))}
            if disk_pixel_size is not None:
                pg = _pixel_geometry(model, disk_pixel_size, disk_centre_px, lamp_direction, per_cell)
                kwargs["pixel_geometry"] = pg
                meta["lamp_geometry"] = {"per_pixel": True, "metres_per_pixel": pg.metres_per_pixel,
                                         "disk_centre_px": list(pg.centre_px), "lamp_direction_deg": lamp_direction}
            elif model == "lamp":
                meta["lamp_geometry"] = {"per_pixel": False, "note": "every pixel inverted with the disk centre's"}
            inv = invert_images(sub[channel], ref[channel], m, d, roi=region, **kwargs)
            summary = inv.summary()
            if not summary["valid"]:
                raise _none_valid(summary["reasons"], roi, submerged)
            terms = all_terms(inv, m, d, inputs)
            total = _total(terms, inv)
            bar.advance(task)
            summary = {**summary, "uncertainty": _unc_summary(terms, inputs)}
            meta.update({"channel": channel, "reasons": {r.name.lower(): int(r) for r in Reason},
                         "summary": summary})
            channels = {"chl_ug_per_L": inv.c_ug_per_L, "chl_unc_ug_per_L": total,
                        **{f"chl_unc_{k}_ug_per_L": v for k, v in terms.items()},
                        "reason": inv.reason.astype(np.float32)}
            write_exr(out, channels, meta)
            bar.advance(task)
        if as_json:
            print_json({**summary, "output": str(out)})
        else:
            console.print(summary_table(summary))
            console.print(f"wrote {out}", markup=False, highlight=False)

    @water.command("simulate")
    def simulate_cmd(out: Path = typer.Option(..., "-o", "--output", help="Output folder.")) -> None:
        """Reproduce the seed's §5 curves (CSV + PNG): the exact eq. 10 beside eq. 11 and the appendix's (k, q)
        model; and the table of C read by eq. 11 and the appendix (as written, corrected, solved) vs the truth."""

        for p in simulate_seed_section5(out):
            console.print(f"wrote {p}")
