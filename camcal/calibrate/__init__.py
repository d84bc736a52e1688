"""Lab frames to a profile: the session index, the frames' screening, the streaming stacks, each stage's
measurement and fit (dark, flat, linearity, sweep, JPEG colour matrix, EMVA 1288) and the run that
calls them all (:mod:`camcal.calibrate.run`).
"""
