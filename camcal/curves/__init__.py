"""c(λ) without a monochromator sweep: curve files both ways, the bundled camera-curve library, the
uncertainty of a borrowed curve, sweeps published as channel means, and reference-target photos
(``camcal profile import-spectral``).
"""
