"""Objective lens stage (package; the code lives in psfs.py during the split)."""

from poevp_optics.camera.objective.psfs import *  # noqa: F401,F403
from poevp_optics.camera.objective.psfs import __doc__  # noqa: F401
