"""`poevp_optics.sources.spectra` is `poevp_optics.core.spectra` (the same module object, so old
imports and monkeypatches reach it). Spectra are shared physical data, used by render/, camera/
and sources/ alike, so they live in core/ (DESIGN's package table, issue 30)."""

import sys

from poevp_optics.core import spectra

sys.modules[__name__] = spectra
