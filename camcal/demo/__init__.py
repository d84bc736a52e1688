"""The whole pipeline end to end on synthetic data (``camcal demo``): a lab camera calibrated from its
session, then survey photos to chlorophyll-a (:mod:`camcal.demo.lab`); a phone calibrated from a
colour chart in the sun, then Secchi photos (:mod:`camcal.demo.phone`). It imports every layer but the
command line.
"""
