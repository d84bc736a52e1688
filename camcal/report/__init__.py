"""What a profile looks like: the self-contained HTML report (:mod:`camcal.report.page`) and every figure
(:mod:`camcal.report.plots`, matplotlib imported inside its functions).
"""
