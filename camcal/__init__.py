"""camcal: turn a consumer camera into a calibrated radiometer for water-quality science.

One sub-package per layer (see ``docs/architecture.md``): ``camcal/io/`` (files in and out),
``camcal/models/`` (what a calibration is: the stages' results, the profile, the correction path),
``camcal/calibrate/`` (lab frames to a profile), ``camcal/curves/`` (c(λ) without a sweep),
``camcal/apply/`` (survey photos to radiance), ``camcal/report/`` (the report and figures),
``camcal/water/`` (the water column, chlorophyll-a, Secchi), ``camcal/cli/`` (the command line) and
``camcal/synth/`` (the synthetic camera, the source of ground truth). Importing camcal has no side effects.
"""

__version__ = "0.1.0"
