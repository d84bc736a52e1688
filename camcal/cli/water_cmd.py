"""``camcal water forward|invert|simulate``: the rendering equation and chlorophyll-a inversion."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import typer

from camcal.cli.common import console, print_json, progress
from camcal.errors import CamcalError


def _model(kind: str, epsilon: str, albedo: float, cutoff_deg: float | None, view_deg: float, n_water: float,
           water_absorption: float, background_absorption: float, reflectance: str):
    from camcal.water.models import SEED_CUTOFF_RAD, RefinedModel, SeedModel
    from camcal.water.units import parse_epsilon_L_per_mol_cm

    eps = parse_epsilon_L_per_mol_cm(epsilon)
    if not (eps > 0 and 0 < albedo < np.inf):
        raise CamcalError("epsilon and albedo must be positive (and finite)")
    if reflectance not in ("fresnel", "schlick"):
        raise CamcalError(f"unknown reflectance {reflectance!r}; use fresnel or schlick")
    if kind in ("seed", "seed-first-order"):
        cut = SEED_CUTOFF_RAD if cutoff_deg is None else np.radians(cutoff_deg)
        if not 0 < cut < np.pi / 2:
            raise CamcalError("cutoff angle must be between 0 and 90 degrees")
        return SeedModel(eps, albedo, float(cut))
    if kind == "refined":
        cut = np.pi / 2 if cutoff_deg is None else np.radians(cutoff_deg)
        if not 0 < cut <= np.pi / 2:
            raise CamcalError("cutoff angle must be above 0 and at most 90 degrees")
        if not 0 <= view_deg < 90:
            raise CamcalError(f"--view-deg must be from 0 to below 90 degrees (from nadir), got {view_deg!r}")
        if not 1 <= n_water < 3:
            raise CamcalError(f"--n-water must be a refractive index from 1 to 3 (water: 1.33), got {n_water!r}")
        for name, value in (("--water-absorption", water_absorption), ("--background-absorption",
                                                                        background_absorption)):
            if not 0 <= value < np.inf:
                raise CamcalError(f"{name} must be a finite absorption >= 0 per m, got {value!r}")
        return RefinedModel(eps, albedo, n_water, float(cut), float(np.radians(view_deg)), water_absorption,
                            background_absorption, reflectance)
    raise CamcalError(f"unknown model {kind!r}; use seed, seed-first-order or refined")


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
    """A disk depth in metres: positive and plausible (:data:`DEPTH_RANGE_M`), else CamcalError."""
    from camcal.water.units import parse_length_m

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


def _roi(text: str | None) -> tuple[int, int, int, int] | None:
    if not text:
        return None
    try:
        x0, y0, w, h = (int(v) for v in text.split(","))
    except ValueError:
        raise CamcalError(f"--roi must be x0,y0,width,height in pixels, got {text!r}") from None
    if w <= 0 or h <= 0 or x0 < 0 or y0 < 0:
        raise CamcalError(f"--roi must have non-negative origin and positive size, got {text!r}")
    return x0, y0, w, h


def register(app: typer.Typer) -> None:
    water = typer.Typer(help="Rendering equation in a water column; chlorophyll-a inversion.", no_args_is_help=True)
    app.add_typer(water, name="water")

    common = dict(
        model=typer.Option("seed", "--model", help="seed (eq. 10 exact), seed-first-order (eq. 11), refined."),
        epsilon=typer.Option("seed", help="ε: '88L/g/cm', '78628L/mol/cm', or seed|porra1989|jeffrey-humphrey1975."),
        albedo=typer.Option(1.0, help="Disk albedo relative to the reference."),
        cutoff_deg=typer.Option(None, help="Cutoff angle θc, degrees (seed: π/2.1; refined: air-side sky cutoff)."),
        view_deg=typer.Option(0.0, help="refined: camera view angle from nadir in air, degrees."),
        n_water=typer.Option(1.33, help="refined: refractive index of water."),
        water_absorption=typer.Option(0.425, help="refined, narrowband: pure-water absorption, m^-1 "
                                       "(Pope & Fry 1997 at 663 nm; --profile uses their full spectrum)."),
        background_absorption=typer.Option(0.0, help="refined: background (CDOM) absorption, m^-1."),
        reflectance=typer.Option("fresnel", help="refined: fresnel (exact) or schlick."),
    )

    @water.command("forward")
    def forward_cmd(
        concentration: str = typer.Option(..., help="Comma list: '1e-7mol/L,2e-7mol/L' or '89ug/L'."),
        depth: str = typer.Option(..., help="Comma list: '10cm,20cm' or '0.2m'."),
        model: str = common["model"], epsilon: str = common["epsilon"], albedo: float = common["albedo"],
        cutoff_deg: float = common["cutoff_deg"], view_deg: float = common["view_deg"],
        n_water: float = common["n_water"], water_absorption: float = common["water_absorption"],
        background_absorption: float = common["background_absorption"], reflectance: str = common["reflectance"],
    ) -> None:
        """Predicted ratio (disk radiance over reference) for each concentration and depth, as JSON."""
        from camcal.water.units import mol_per_L_to_ug_per_L, parse_concentration_mol_per_L

        m = _model(model, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption, background_absorption,
                   reflectance)
        c = _list(concentration, parse_concentration_mol_per_L, "concentration")
        d = _list(depth, _depth, "depth")
        if np.any(c < 0):
            raise CamcalError(f"concentrations must be >= 0, got {concentration!r}")
        if np.any(c > MAX_CONCENTRATION_MOL_PER_L):
            raise CamcalError(f"concentration {concentration!r} is implausible: at most "
                              f"{MAX_CONCENTRATION_MOL_PER_L:g} mol/L")
        with np.errstate(all="ignore"):  # extreme optical depths: the ratio underflows to 0 (or NaN -> null)
            ratio = m.ratio_first_order(c[None, :], d[:, None]) if model == "seed-first-order" else m.ratio(
                c[None, :], d[:, None])
        print_json({"model": model, "depth_m": d.tolist(), "c_mol_per_L": c.tolist(),
                    "c_ug_per_L": mol_per_L_to_ug_per_L(c).tolist(), "ratio": _json_nested(ratio)})

    @water.command("invert")
    def invert_cmd(
        depth: str = typer.Option(..., help="Disk depth: '0.2m' or '20cm'."),
        submerged: Path = typer.Option(None, help="EXR with the submerged disk's radiance."),
        reference: Path = typer.Option(None, help="EXR with the reference radiance (same channel)."),
        channel: str = typer.Option(None, help="EXR channel to read from both files (default L663; R with --profile)."),
        sigma_channel: str = typer.Option(None, help="EXR channel with the 1-σ radiance uncertainty (both files)."),
        relative_sigma: float = typer.Option(None, help="Relative 1-σ uncertainty of the ratio (instead of maps)."),
        roi: str = typer.Option(None, help="Region x0,y0,width,height in pixels; other pixels become NaN."),
        ratio: str = typer.Option(None, help="Numbers only: comma list of ratios; prints JSON."),
        out: Path = typer.Option(None, "-o", "--out", help="Output EXR (chl_ug_per_L, chl_unc_ug_per_L, reason)."),
        profile: Path = typer.Option(None, "--profile", help="Calibration profile: band-aware inversion over its "
                                     "c(λ) (the images hold band radiances, as `camcal apply` writes)."),
        band_channel: str = typer.Option("R", help="With --profile: the channel whose c(λ) defines the band."),
        illuminant: str = typer.Option("D65", help="With --profile: the light's spectrum (flat, D65, A, ...)."),
        chlorophyll_csv: Path = typer.Option(None, help="With --profile: a_chl(λ) CSV (default Bricaud 1998)."),
        model: str = common["model"], epsilon: str = common["epsilon"], albedo: float = common["albedo"],
        cutoff_deg: float = common["cutoff_deg"], view_deg: float = common["view_deg"],
        n_water: float = common["n_water"], water_absorption: float = common["water_absorption"],
        background_absorption: float = common["background_absorption"], reflectance: str = common["reflectance"],
    ) -> None:
        """Chlorophyll-a per pixel from a submerged and a reference radiance image (or from numbers).

        Narrowband by default (the images are radiances at the wavelength of --epsilon); with --profile,
        band-aware: the ratio is predicted by integrating the model over the profile's c(λ) of
        --band-channel with Pope & Fry (1997) water (refined model) and a chlorophyll spectrum.
        """
        from camcal.water.invert import Reason, invert_images, invert_ratio
        d = _depth(depth)
        if relative_sigma is not None and not (np.isfinite(relative_sigma) and relative_sigma >= 0):
            raise CamcalError(f"--relative-sigma must be a finite number >= 0, got {relative_sigma!r}")
        if model == "seed-first-order":
            raise CamcalError("invert uses the exact models: choose --model seed or refined")
        m = _model(model, epsilon, albedo, cutoff_deg, view_deg, n_water, water_absorption, background_absorption,
                   reflectance)
        meta = {"model": model, "depth_m": d}
        if profile is not None:
            from camcal.water.band import band_model_from_profile, read_chlorophyll_csv

            chl = read_chlorophyll_csv(chlorophyll_csv) if chlorophyll_csv else None
            m = band_model_from_profile(profile, band_channel, geometry=m, chlorophyll=chl, illuminant=illuminant,
                                        background_absorption_per_m=background_absorption)
            meta.update({"inversion": "band", "profile": str(profile), "band_channel": band_channel,
                         "illuminant": illuminant, "band_model": m.describe()})
            channel = channel or band_channel
        else:
            meta.update({"inversion": "narrowband", "epsilon_L_per_mol_cm": m.epsilon_L_per_mol_cm})
            channel = channel or "L663"
        if ratio is not None:
            r = _list(ratio, _ratio, "ratio")
            if profile is not None:
                inv = m.inverse(d).concentration(r, sigma_ln_ratio=relative_sigma)
            else:
                inv = invert_ratio(r, m, d, sigma_ln_ratio=relative_sigma)
            print_json({**meta, "ratio": _json_list(r), "c_mol_per_L": _json_list(inv.c_mol_per_L),
                        "c_ug_per_L": _json_list(inv.c_ug_per_L), "sigma_ug_per_L": _json_list(inv.sigma_ug_per_L),
                        "reason": [Reason(int(v)).name.lower() for v in inv.reason]})
            return
        if submerged is None or reference is None or out is None:
            raise CamcalError("give --submerged A.exr --reference B.exr -o chl.exr, or --ratio for numbers")
        from camcal.exr import read_exr, write_exr

        names = [channel] + ([sigma_channel] if sigma_channel else [])
        with progress() as bar:
            task = bar.add_task("inverting", total=3)
            sub, _ = read_exr(submerged, names)
            ref, _ = read_exr(reference, names)
            (h, w), (rh, rw) = sub[channel].shape, ref[channel].shape
            if (h, w) != (rh, rw):
                raise CamcalError(f"is {w}x{h} pixels but the reference {reference.name} is {rw}x{rh}; the two images "
                                  "must have one size (same camera, same crop)", submerged)
            region = _roi(roi)
            if region is not None and (region[0] >= w or region[1] >= h):
                raise CamcalError(f"--roi {roi} lies outside the image ({w}x{h} pixels)", submerged)
            bar.advance(task)
            kwargs = {}
            if sigma_channel:
                kwargs = {"sigma_submerged": sub[sigma_channel], "sigma_reference": ref[sigma_channel]}
            elif relative_sigma is not None:
                kwargs = {"sigma_submerged": relative_sigma * np.abs(sub[channel].astype(float))}
            inv = invert_images(sub[channel], ref[channel], m, d, roi=region, **kwargs)
            bar.advance(task)
            meta.update({"channel": channel, "reasons": {r.name.lower(): int(r) for r in Reason},
                         "summary": inv.summary()})
            write_exr(out, {"chl_ug_per_L": inv.c_ug_per_L, "chl_unc_ug_per_L": inv.sigma_ug_per_L,
                            "reason": inv.reason.astype(np.float32)}, meta)
            bar.advance(task)
        console.print(json.dumps(inv.summary()))
        console.print(f"wrote {out}")

    @water.command("simulate")
    def simulate_cmd(out: Path = typer.Option(..., "-o", "--out", help="Output folder.")) -> None:
        """Reproduce the seed's §5 curves (CSV + PNG), the exact eq. 10 beside eq. 11."""
        from camcal.water.simulate import simulate_seed_section5

        for p in simulate_seed_section5(out):
            console.print(f"wrote {p}")
