"""XML parameters that this package's plugins take from the scene file (called by render.plan_spectra).

* `[spectra.X] distribution = "file:..."` binds `$X_distribution` (an absolute path) for the
  `photometric` emitters whose `intensity` is `$X`.
* `[sheeting.Y]` binds `$Y` (the `sheeting` string of `retroreflective` BSDFs).
* `[marking.Z]` binds `$Z` (the `marking` string of `road_marking` BSDFs).

The XML is checked against the TOML in both directions; each error is one line naming the file
and the key.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from poevp_optics.core.exceptions import SceneError
from poevp_optics.render.materials.photometric_lamp import resolve_distribution
from poevp_optics.render.materials.retroreflective import sheeting_string


def _param(node, tag, name):
    for child in node.iter(tag):
        if child.get("name") == name:
            v = (child.get("value") or "").strip()
            return v[1:] if v.startswith("$") else None
    return None


def plugin_xml_params(scene, defaults: frozenset[str]) -> dict[str, str]:
    """XML parameter values for photometric lamps and retroreflective sheeting."""
    file, xml = scene.toml_path, scene.xml_path
    root = ET.parse(xml).getroot()
    params: dict[str, str] = {}
    for name, entry in scene.spectra.items():
        if entry.distribution:
            key = f"{name}_distribution"
            if key not in defaults:
                raise SceneError(f"{file}: spectra.{name}.distribution: the XML {xml.name} declares no "
                                 f"<default name=\"{key}\"> (use it as <string name=\"distribution\" "
                                 f"value=\"${key}\"/> in a photometric emitter)")
            params[key] = str(resolve_distribution(entry.distribution, file.parent))
    for name, entry in scene.sheeting.items():
        if name not in defaults:
            raise SceneError(f"{file}: sheeting.{name}: the XML {xml.name} declares no "
                             f"<default name=\"{name}\"> (use it as <string name=\"sheeting\" "
                             f"value=\"${name}\"/> in a retroreflective BSDF)")
        params[name] = sheeting_string(entry, file.parent)
    for name in getattr(scene, "marking", {}):
        if name not in defaults:
            raise SceneError(f"{file}: marking.{name}: the XML {xml.name} declares no "
                             f"<default name=\"{name}\"> (use it as <string name=\"marking\" "
                             f"value=\"${name}\"/> in a road_marking BSDF)")
        params[name] = scene.marking[name].source
    for em in root.iter("emitter"):
        if em.get("type") != "photometric":
            continue
        ident = em.get("id") or "photometric"
        lamp = _param(em, "spectrum", "intensity")
        dist = _param(em, "string", "distribution")
        entry = scene.spectra.get(lamp) if lamp else None
        if entry is None or not entry.distribution:
            raise SceneError(f"{file}: spectra.{lamp}.distribution: photometric emitter {ident!r} of "
                             f"{xml.name} needs its intensity ${lamp} to name a photometric file")
        if dist != f"{lamp}_distribution":
            raise SceneError(f"{xml}: emitter {ident!r}: distribution must be \"${lamp}_distribution\" "
                             f"(the file of [spectra.{lamp}])")
    for bsdf in root.iter("bsdf"):
        if bsdf.get("type") != "retroreflective":
            continue
        name = _param(bsdf, "string", "sheeting")
        if name is not None and name not in scene.sheeting:
            raise SceneError(f"{file}: sheeting.{name}: retroreflective BSDF in {xml.name} uses "
                             f"${name}, which has no [sheeting.{name}] entry")
    return params
