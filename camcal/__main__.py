"""``python -m camcal``."""

from camcal.cli import run

run()
