"""The XML parameters of the road-world sections: [weather] (sources/weather.py),
[vehicle.<id>] (sources/vehicles.py) and [furniture.<id>] (sources/furniture.py), checked against
the XML's declared parameters.

[weather] binds the `$weather_*` parameters the XML declares, and requires the fog ones when
fog_visibility_m > 0 and the water ones when wetness > 0. Each [vehicle.<id>] requires its parts'
meshes and `$vehicle_<id>_matrix`, and with a plate_text its plate's matrix and texture; the
headlamps' emitter matrices (and a plate's matrix without a text) are bound where declared. Each
[furniture.<id>] requires its parts' meshes, `$furniture_<id>_matrix`, and for a sign its face's
matrix and texture. Each missing one is one line naming the file and the key.
"""

from __future__ import annotations

from poevp_optics.core.exceptions import SceneError


def world_xml_params(scene, defaults: frozenset[str]) -> dict[str, str]:
    """`$weather_*` and `$vehicle_<id>_*` values for the scene's XML (module docstring)."""
    file, xml = scene.toml_path, scene.xml_path
    params: dict[str, str] = {}
    weather = getattr(scene, "weather", None)
    if weather is not None:
        from poevp_optics.sources import weather as w

        for name, key in w.required_params(weather).items():
            if name not in defaults:
                raise SceneError(f"{file}: {key}: the XML {xml.name} declares no <default name=\"{name}\">")
        params.update({k: v for k, v in w.xml_params(weather).items() if k in defaults})
    for ident, spec in getattr(scene, "vehicle", {}).items():
        from poevp_optics.sources.vehicles import xml_params as vehicle_params

        values = vehicle_params(ident, spec)
        pre = f"vehicle_{ident}"
        for name in sorted(values):
            if name not in defaults and not name.endswith(("_plate_texture", "_plate_matrix", "_headlamp_left_matrix",
                                                            "_headlamp_right_matrix")):
                raise SceneError(f"{file}: vehicle.{ident}: the XML {xml.name} declares no "
                                 f"<default name=\"{name}\">")
        for name in (f"{pre}_plate_texture", f"{pre}_plate_matrix"):
            if spec.plate_text and name not in defaults:
                raise SceneError(f"{file}: vehicle.{ident}.plate_text: the XML {xml.name} declares no "
                                 f"<default name=\"{name}\"> (the plate's rectangle and texture)")
        params.update({k: v for k, v in values.items() if k in defaults})
    for ident, spec in getattr(scene, "furniture", {}).items():
        from poevp_optics.sources.furniture import required_params, xml_params as furniture_params

        for name in required_params(ident, spec):
            if name not in defaults:
                raise SceneError(f"{file}: furniture.{ident}: the XML {xml.name} declares no "
                                 f"<default name=\"{name}\">")
        params.update(furniture_params(ident, spec))
    return params
