"""poevp_optics: physically based simulator of the POE-VP DMD camera.

Stages (see DESIGN.md): scene -> render (Mitsuba, spectral) -> DMD (DrJit PWM) -> relay (PSF)
-> sensor (noise, ADC) -> reconstruct; the mask loop closes through a torch predictor.
"""

__version__ = "0.2.0"
