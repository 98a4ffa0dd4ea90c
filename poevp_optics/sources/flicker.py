"""`poevp_optics.sources.flicker` is `poevp_optics.core.flicker` (the same module object, so old
imports and monkeypatches reach it). The lamp drive is a shared physical model: render/ averages
it over sub-frames and camera/ integrates it per DMD level, so it lives in core/ (DESIGN's
package table, issue 30)."""

import sys

from poevp_optics.core import flicker

sys.modules[__name__] = flicker
