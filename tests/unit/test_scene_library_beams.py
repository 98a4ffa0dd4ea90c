"""benchmarks/scene_library.py scales *our own* beams: in every library scene the spectrum it picks
is the one of the photometric emitters mounted on our car (placed within 2 m of the camera in the
XML), the emitters elsewhere that share it are named, and a gain g multiplies that spectrum's
intensity_cd by g. Independent of the picker's rule (emitter ids, [road] highbeam): here an
emitter is ours by where the XML puts it."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest

from benchmarks.scene_library import LIBRARY, own_beams, scene_overrides
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


def _vec(text: str, defaults: dict) -> np.ndarray | None:
    text = defaults.get(text[1:], text) if text.startswith("$") else text
    try:
        return np.array([float(v) for v in text.replace(",", " ").split()])
    except ValueError:
        return None


def _emitters_by_place(xml_path):
    """(camera origin, [(emitter id, $intensity name, lookat origin or None)]) of a scene XML."""
    root = ET.parse(xml_path).getroot()
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    cam = _vec(next(root.iter("sensor")).find(".//lookat").get("origin"), defaults)
    out = []
    for em in root.iter("emitter"):
        if em.get("type") != "photometric":
            continue
        look = em.find("./transform/lookat")
        origin = _vec(look.get("origin"), defaults) if look is not None else None
        name = next(sp.get("value")[1:] for sp in em.iter("spectrum") if sp.get("name") == "intensity")
        out.append((em.get("id"), name, origin))
    return cam, out


@pytest.mark.parametrize("name", LIBRARY)
def test_the_beams_scaled_are_the_ones_on_our_car(name):
    spec = load_scene(SCENES / name, [])
    beam, shared = own_beams(spec)
    cam, emitters = _emitters_by_place(spec.xml_path)
    ours = [(e, n) for e, n, o in emitters if o is not None and np.linalg.norm(o - cam) < 2.0]
    assert len(ours) == 2 and {n for _, n in ours} == {beam}
    assert shared == sorted(e for e, n, _ in emitters if n == beam and e not in {i for i, _ in ours})


def test_a_gain_multiplies_our_beams_intensity_only():
    scene = SCENES / "toll_or_junction"
    sets, beam, _ = scene_overrides(str(scene), 1.0, 3, 10.0, [])
    base = load_scene(scene, []).spectra[beam].intensity_cd
    scaled = [s for s in sets if s.startswith("spectra.")]
    assert len(scaled) == 1 and scaled[0].startswith(f"spectra.{beam}.intensity_cd=")
    assert float(scaled[0].split("=")[1]) == pytest.approx(10 * base, rel=1e-9)
