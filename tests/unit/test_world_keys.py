"""[weather] and [marking.<param>] keys: bad values and XML parameters the scene needs but its XML
does not declare are one line naming the file and the key."""

from __future__ import annotations

import math

import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.render.renderer import plan_spectra
from poevp_optics.scene.load import load_scene
from poevp_optics.sources.weather import WeatherSpec, extinction_per_m, xml_params

XML = """\
<scene version="3.0.0">
    {defaults}
    <sensor type="perspective"><float name="fov" value="10"/></sensor>
</scene>
"""


def test_bad_weather_values_name_their_key(write_scene):
    for i, (line, key) in enumerate([("fog_visibility_m = -5.0", "weather.fog_visibility_m"),
                                     ("fog_asymmetry = 1.0", "weather.fog_asymmetry"),
                                     ("fog_contrast_threshold = 0.0", "weather.fog_contrast_threshold"),
                                     ("wetness = 1.5", "weather.wetness"), ("rain_mm = 3.0", "weather.rain_mm")]):
        folder = write_scene(f"[weather]\n{line}\n", XML.format(defaults=""), name=f"w{i}")
        with pytest.raises(SceneError) as e:
            load_scene(folder)
        assert key in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_undeclared_world_parameters_are_one_line(write_scene):
    cases = [("[weather]\nfog_visibility_m = 100.0\n", "weather.fog_visibility_m", "weather_fog_sigma_t"),
             ("[weather]\nwetness = 0.5\n", "weather.wetness", "weather_wetness"),
             ("[marking.lane]\nsource = \"en1436:R3\"\n", "marking.lane", "lane")]
    for i, (toml, key, param) in enumerate(cases):
        folder = write_scene(toml, XML.format(defaults=""), name=f"u{i}")
        with pytest.raises(SceneError) as e:
            plan_spectra(load_scene(folder).resolved.render)
        assert key in str(e.value) and param in str(e.value) and "\n" not in str(e.value), str(e.value)


def test_weather_binds_only_what_the_xml_declares(write_scene):
    folder = write_scene("[weather]\nfog_visibility_m = 150.0\nfog_contrast_threshold = 0.02\n",
                         XML.format(defaults="\n".join(f'<default name="{n}" value="0"/>' for n in
                                                       ("weather_fog_sigma_t", "weather_fog_albedo", "weather_fog_g"))),
                         name="fog")
    params = plan_spectra(load_scene(folder).resolved.render).xml_params
    assert float(params["weather_fog_sigma_t"]) == pytest.approx(math.log(50.0) / 150.0, rel=1e-8)
    assert "weather_wetness" not in params


def test_koschmieder_extinction():
    # 5 % threshold (WMO MOR): 2.996 / V; 2 % (Koschmieder): 3.912 / V
    assert extinction_per_m(1000.0) == pytest.approx(2.9957 / 1000.0, rel=1e-4)
    assert extinction_per_m(1000.0, 0.02) == pytest.approx(3.9120 / 1000.0, rel=1e-4)
    assert WeatherSpec().extinction_per_m() == 0.0
    assert float(xml_params(WeatherSpec(fog_visibility_m=200.0))["weather_fog_sigma_t"]) == pytest.approx(
        math.log(20.0) / 200.0, rel=1e-8)
    with pytest.raises(ValueError):
        extinction_per_m(0.0)
