"""camcal: turn a consumer camera into a calibrated radiometer for water-quality science.

Pipeline stages, one module each (see ``docs/architecture.md``): :mod:`camcal.io`
(frames), :mod:`camcal.stack` (streaming combination), :mod:`camcal.dark`,
:mod:`camcal.flat`, :mod:`camcal.response`, :mod:`camcal.spectral`,
:mod:`camcal.profile`, :mod:`camcal.apply`, :mod:`camcal.water`; the synthetic
camera is :mod:`camcal.synth`. Importing camcal has no side effects.
"""

__version__ = "0.1.0"
