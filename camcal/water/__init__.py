"""The water module: the seed's rendering equation (exact and refined) and chlorophyll-a inversion.

See docs/water.md for the physics, the defaults and their citations.
"""

from camcal.water.band import (
    BandInverse,
    BandModel,
    ChlorophyllAbsorption,
    band_model_from_profile,
    bricaud_1998,
    illuminant_spectrum,
    read_absorber_csv,
    read_chlorophyll_csv,
)
from camcal.water.invert import Inversion, Reason, TauTable, invert_images, invert_ratio, tau_newton, tau_table
from camcal.water.models import (
    ClosedForm,
    ExactTransmittanceForm,
    ExponentialForm,
    LampModel,
    RefinedModel,
    SeedModel,
    e3_integral,
    e3_integral_derivative,
    lamp_ratio,
)
from camcal.water.purewater import pope_fry_1997, pure_water_absorption_per_m
from camcal.water.simulate import simulate_seed_section5

__all__ = [
    "BandInverse", "BandModel", "ChlorophyllAbsorption", "ClosedForm", "ExactTransmittanceForm", "ExponentialForm",
    "Inversion", "LampModel", "Reason", "RefinedModel", "read_absorber_csv",
    "SeedModel", "TauTable", "band_model_from_profile", "bricaud_1998", "e3_integral", "e3_integral_derivative",
    "illuminant_spectrum", "invert_images", "invert_ratio", "lamp_ratio", "pope_fry_1997",
    "pure_water_absorption_per_m", "read_chlorophyll_csv", "simulate_seed_section5", "tau_newton", "tau_table",
]
