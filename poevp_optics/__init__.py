"""poevp_optics: physically based simulator of the POE-VP DMD camera.

Stages (see DESIGN.md): scene -> render (Mitsuba, spectral) -> DMD (DrJit PWM) -> relay (PSF)
-> sensor (noise, ADC) -> reconstruct; the mask loop closes through a torch predictor.
"""

from poevp_optics.core.version import __version__  # noqa: F401 (the one definition is core/version.py)
