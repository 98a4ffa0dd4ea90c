"""Rendering (DESIGN.md `render/`): the Mitsuba renderer, exposures, and the materials and emitters
registered from Python, which core.runtime.set_variant registers with every variant it activates
(the hook installed here, so that core/ need not import render/)."""

from poevp_optics.core import runtime
from poevp_optics.render.materials import register_plugins

runtime.on_variant(register_plugins)
