"""Weather on the road: fog as a participating medium, and a water film on the asphalt.

[weather] keys (`WeatherSpec`; bound into the XML as `$weather_*` parameters by `xml_params`):

| key                    | type  | unit | default | meaning |
|------------------------|-------|------|---------|---------|
| fog_visibility_m       | float | m    | 0       | meteorological optical range V of the fog; 0: no fog (extinction 0) |
| fog_contrast_threshold | float | 1    | 0.05    | contrast (or transmittance) threshold that defines V: 0.05 WMO's MOR, 0.02 Koschmieder's |
| fog_albedo             | float | 1    | 0.999   | single-scattering albedo of the droplets |
| fog_asymmetry          | float | 1    | 0.85    | Henyey-Greenstein g of the droplets' phase function (forward scattering: the lamps' haloes) |
| wetness                | float | 1    | 0       | fraction of the road under a water film (blend weight of the wet and the dry asphalt) |
| water_roughness        | float | 1    | 0.02    | GGX alpha of the water surface (its ripples stretch a lamp's mirror image into a streak) |

Fog. Koschmieder's law (Koschmieder 1924, "Theorie der horizontalen Sichtweite"): a black object
seen against the horizon sky keeps the contrast C = exp(-sigma d) at distance d, sigma the
extinction coefficient; the visibility V is where C falls to the threshold epsilon, so
sigma = ln(1 / epsilon) / V. The World Meteorological Organization's meteorological optical range
(WMO-No. 8, Guide to Instruments and Methods of Observation, 2018, Vol. I ch. 9; CIE e-ILV
17-21-019) is the path that reduces a collimated beam's flux to 5 %: epsilon = 0.05,
sigma = ln(20) / V = 2.996 / V, the default here (what a weather station reports); Koschmieder's
2 % contrast gives sigma = ln(50) / V = 3.912 / V (`fog_contrast_threshold = 0.02`). Fog is
V < 1 km, thick fog V < 200 m. Droplets (2-20 um) hardly absorb in the visible (the imaginary
part of water's index is ~1e-9 at 500 nm: Hale & Querry 1973, Appl. Opt. 12, 555), so the
albedo is close to 1; their Mie phase function is forward-peaked, commonly modelled by a
Henyey-Greenstein function with g = 0.8-0.9. In the XML the fog is a Mitsuba `homogeneous`
medium (`sigma_t` = $weather_fog_sigma_t in m-1, `albedo`, a `hg` phase with g) filling a
`null`-BSDF box around the scene, with the camera inside it (the sensor's `medium`) and every
shape's `exterior` set to it; the integrator is `volpath` with max_depth 2, or `single_scatter`
(render/materials/single_scatter.py: the same single scattering with the fog's transmittance in
closed form, fog_highway's).

Wet road. A water film over the asphalt is a smooth (or rippled) dielectric interface over a
diffuse base: Mitsuba's `plastic` (smooth) or `roughplastic` (GGX ripples) with `int_ior` water
1.333 (at 589 nm, 20 C: Hale & Querry 1973; IAPWS R9-97 gives 1.3330) and `ext_ior` air 1.000277
(Ciddor 1996, Appl. Opt. 35, 1566, at 589 nm, 15 C, 101.325 kPa). Its specular reflectance is
Fresnel's, 2 % at normal incidence and rising toward grazing (the angles a driver sees the road
at), where every lamp gets a mirror image. The dry and the wet asphalt are blended by `wetness`
in a `blendbsdf` (the area fraction under water).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from poevp_optics.core.params import param

#: Refractive index of water at 589 nm, 20 C (Hale & Querry 1973; IAPWS R9-97: 1.3330).
WATER_IOR = 1.333
#: Refractive index of air at 589 nm, 15 C, 101.325 kPa (Ciddor 1996).
AIR_IOR = 1.000277


@dataclass(frozen=True)
class WeatherSpec:
    """[weather]: fog and a wet road (module docstring)."""

    fog_visibility_m: float = param(0.0, min=0.0, max=1e5)
    fog_contrast_threshold: float = param(0.05, gt=0.0, lt=1.0)
    fog_albedo: float = param(0.999, min=0.0, max=1.0)
    fog_asymmetry: float = param(0.85, gt=-1.0, lt=1.0)
    wetness: float = param(0.0, min=0.0, max=1.0)
    water_roughness: float = param(0.02, gt=0.0, max=1.0)

    @property
    def has_fog(self) -> bool:
        return self.fog_visibility_m > 0

    def extinction_per_m(self) -> float:
        """Fog extinction coefficient sigma = ln(1 / threshold) / V (m-1); 0 without fog."""
        return extinction_per_m(self.fog_visibility_m, self.fog_contrast_threshold) if self.has_fog else 0.0


def extinction_per_m(visibility_m: float, contrast_threshold: float = 0.05) -> float:
    """Koschmieder: sigma = ln(1 / epsilon) / V (m-1) for visibility V (m) at threshold epsilon."""
    if not visibility_m > 0 or not 0 < contrast_threshold < 1:
        raise ValueError(f"visibility {visibility_m} m must be > 0 and the threshold in (0, 1)")
    return math.log(1.0 / contrast_threshold) / visibility_m


#: XML parameters of [weather]: fog ones, water ones (the ripples' `weather_water_alpha` is bound
#: where declared: a smooth `plastic` film has none).
FOG_PARAMS = ("weather_fog_sigma_t", "weather_fog_albedo", "weather_fog_g")
WATER_PARAMS = ("weather_wetness", "weather_water_ior", "weather_air_ior")


def xml_params(weather: WeatherSpec) -> dict[str, str]:
    """Every `$weather_*` XML parameter (the binder passes those the XML declares)."""
    return {"weather_fog_sigma_t": f"{weather.extinction_per_m():.9g}",
            "weather_fog_albedo": f"{weather.fog_albedo:.9g}",
            "weather_fog_g": f"{weather.fog_asymmetry:.9g}",
            "weather_wetness": f"{weather.wetness:.9g}",
            "weather_water_alpha": f"{weather.water_roughness:.9g}",
            "weather_water_ior": f"{WATER_IOR:.9g}", "weather_air_ior": f"{AIR_IOR:.9g}"}


def required_params(weather: WeatherSpec) -> dict[str, str]:
    """The XML parameters a scene's [weather] needs declared, with the key that asks for them:
    fog ones when fog_visibility_m > 0, water ones when wetness > 0."""
    out = {}
    if weather.has_fog:
        out.update({p: "weather.fog_visibility_m" for p in FOG_PARAMS})
    if weather.wetness > 0:
        out.update({p: "weather.wetness" for p in WATER_PARAMS})
    return out


def wet_road_bsdf(asphalt_reflectance, roughness: float = 0.0, wetness: float = 1.0) -> dict:
    """A Mitsuba dict of the wet road: `plastic` (roughness 0) or `roughplastic` (GGX alpha) with
    water over air on the asphalt's diffuse reflectance, blended with the dry asphalt by wetness
    (1: all wet, the bare plastic)."""
    wet = {"type": "plastic" if roughness == 0 else "roughplastic", "int_ior": WATER_IOR, "ext_ior": AIR_IOR,
           "diffuse_reflectance": asphalt_reflectance}
    if roughness:
        wet.update(distribution="ggx", alpha=roughness)
    if wetness >= 1:
        return wet
    dry = {"type": "diffuse", "reflectance": asphalt_reflectance}
    return {"type": "blendbsdf", "weight": wetness, "dry": dry, "wet": wet}
