"""A profile applied to survey photos: one photo (:mod:`camcal.apply.photo`), the radiance estimators at
λ0 (:mod:`camcal.apply.radiance`) and batches on a process pool or Dask (:mod:`camcal.apply.batch`).
"""
