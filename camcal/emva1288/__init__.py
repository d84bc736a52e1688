"""The data sheet of an EMVA 1288 measurement (release 4.0): its ``emva1288`` JSON section, its HTML page
and its figures. The measurement's figures and its descriptor file are in ``camcal/calibrate/``.
"""
