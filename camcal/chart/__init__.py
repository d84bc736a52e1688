"""Spectral sensitivity from a colour chart: the chart's reflectances, the light on it, a basis of camera
curves and the recovery of c(λ) from the chart's patch signals (pure functions: arrays in, dataclasses out)."""
