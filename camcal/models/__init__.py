"""What a calibration is: each stage's result (dark, flat, response, spectral sensitivity, EMVA 1288 sheet) as
dataclasses with their evaluation and files, the profile, the one correction path, exposure
normalisation, camera identity and reference spectra.

Never imports ``camcal/calibrate/`` (a stage's measurement or fit): reading or applying a profile
loads no fitting code.
"""
