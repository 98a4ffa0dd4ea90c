"""Materials and emitters written in Python and registered with Mitsuba (DESIGN.md `render/`).

| plugin (XML type)  | module                 | what |
|--------------------|------------------------|------|
| `retroreflective`  | `retroreflective.py`   | licence-plate sheeting from an R_A(observation, entrance) table (ASTM D4956 presets) |
| `photometric`      | `photometric_lamp.py`  | point lamp whose candela table comes from an IES LM-63 or EULUMDAT file |
| `road_marking`     | `road_marking.py`      | lane marking with an EN 1436 R_L class (the sheeting model with a marking's table) |
| `single_scatter`   | `single_scatter.py`    | integrator: single scattering in a homogeneous fog with closed-form transmittance |

`register_plugins()` is called by `runtime.set_variant` right after `mi.set_variant`, once per
variant (Mitsuba keeps a plugin registry per variant); nothing else registers plugins.
"""

from __future__ import annotations

_REGISTERED: set[str] = set()


def register_plugins() -> None:
    """Register this package's plugins with the active Mitsuba variant (idempotent)."""
    import mitsuba as mi

    variant = mi.variant()
    if variant in _REGISTERED:
        return
    from poevp_optics.render.materials import photometric_lamp, retroreflective, road_marking, single_scatter

    retroreflective.register()
    photometric_lamp.register()
    road_marking.register()
    single_scatter.register()
    _REGISTERED.add(variant)
