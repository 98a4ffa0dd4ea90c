"""Spectra: emitter SPDs, reflectances and sensor QE on one wavelength grid.

Sources are named by a short string so scene files stay data:

| source                         | what                                        | reference |
|--------------------------------|---------------------------------------------|-----------|
| ``cie:A``                      | CIE illuminant A (halogen / tungsten, 2856 K)| CIE 015:2018 via colour-science |
| ``cie:LED-B1`` ... ``LED-V2``  | CIE LED illuminants (measured white LEDs)   | CIE 015:2018 Table 11, via colour-science |
| ``colorchecker:<patch>``       | measured ColorChecker reflectance           | Ohta (1997) "ColorChecker N Ohta", via colour-science |
| ``file:<path>``                | two-column CSV (wavelength_nm, value), ``#`` comments; relative to ``assets/`` | the file's own header |
| ``neutral:<value>`` or a number| spectrally flat value                       | - |

Emission spectra and QE are zero outside their tables; reflectances hold their edge values.
Absolute emitter scale comes from a photometric quantity (cd, cd m-2, lx) with the CIE 1924
photopic V(lambda) and K_m = 683.002 lm W-1 (`units.py`).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np

from poevp_optics.core.units import LUMINOUS_EFFICACY_MAX_LM_PER_W, photons_per_joule
from poevp_optics.core.exceptions import UserError
from poevp_optics.core.paths import ASSETS_DIR  # noqa: F401 (re-exported)
from dataclasses import dataclass
from poevp_optics.core.params import param


@dataclass(frozen=True)
class SpectrumSpec:
    """[spectra.<param>]: a spectrum bound to the XML parameter `$<param>`.

    kind: "intensity" (W sr-1 nm-1, scaled by intensity_cd), "radiance" (W m-2 sr-1 nm-1,
    luminance_cd_per_m2), "irradiance" (W m-2 nm-1, illuminance_lux) or "reflectance"
    (unitless, times `scale`, must stay <= 1); `distribution` (intensity only): a photometric
    file (.ies/.ldt) shaping the lamp (render/materials/photometric_lamp.py).
    """

    kind: str = param(choices=("intensity", "radiance", "irradiance", "reflectance"))
    source: str = param()
    intensity_cd: float = param(math.nan, min=0)
    luminance_cd_per_m2: float = param(math.nan, min=0)
    illuminance_lux: float = param(math.nan, min=0)
    scale: float = param(1.0, min=0)
    distribution: str = param("")

#: Rendering grid (nm): Mitsuba's spectral range is 360-830 nm.
WAVELENGTH_MIN_NM = 360.0
WAVELENGTH_MAX_NM = 830.0
WAVELENGTH_STEP_NM = 5.0
WAVELENGTHS_NM = np.arange(WAVELENGTH_MIN_NM, WAVELENGTH_MAX_NM + 0.5 * WAVELENGTH_STEP_NM,
                           WAVELENGTH_STEP_NM)




class SpectrumError(UserError):
    """A spectrum source that cannot be resolved."""


def _on_grid(wl_nm: np.ndarray, values: np.ndarray, *, hold_edges: bool) -> np.ndarray:
    order = np.argsort(wl_nm)
    wl_nm, values = wl_nm[order], values[order]
    if hold_edges:
        return np.interp(WAVELENGTHS_NM, wl_nm, values)
    return np.interp(WAVELENGTHS_NM, wl_nm, values, left=0.0, right=0.0)


#: CIE daylight illuminants whose table colour-science ends at 780 nm: continued to 830 nm by
#: the CIE D-series generating function (S0 + M1 S1 + M2 S2; CIE 015:2018 Sec. 4.1) at the
#: illuminant's chromaticity, scaled to meet the table at its last row.
_D_SERIES = ("D50", "D55", "D60", "D65", "D75")


@functools.lru_cache(maxsize=64)
def _colour_sd(kind: str, name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(wavelengths nm, values) of a colour-science dataset (`_colour_sd_build`), kept in the
    package cache keyed by colour-science's version (`_colour_dataset`)."""
    wl, vals = _colour_dataset(kind, name, lambda: _colour_sd_build(kind, name))
    return tuple(map(float, wl)), tuple(map(float, vals))


def _colour_dataset(kind: str, name: str, build) -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths nm, values) that `build()` reads from colour-science, stored in the package
    cache (spectra/, a SHA-256 of kind, name and colour-science's version): importing colour
    costs 1.7 s a process (it imports its plotting, matplotlib and pandas), so a run that only
    needs its tables reads them from there. Bit-identical: float64 arrays in an .npz."""
    from importlib.metadata import version

    from poevp_optics.core.cache import cache_file, cached, digest, save_npz

    key = digest(f"{kind}\0{name}\0colour-science {version('colour-science')}", algo="sha256", length=32)

    def load(path):
        with np.load(path) as z:
            return np.asarray(z["wavelengths_nm"], np.float64), np.asarray(z["values"], np.float64)

    def problem(pair) -> str | None:
        wl, vals = pair
        if wl.ndim != 1 or wl.shape != vals.shape or wl.size < 2:
            return f"tables of shapes {wl.shape} and {vals.shape}, not two equal 1-D tables"
        if not (np.all(np.isfinite(wl)) and np.all(np.isfinite(vals))):
            return "non-finite values"
        return None

    def save(path, pair):
        save_npz(path, {"wavelengths_nm": pair[0], "values": pair[1]})

    def made():
        wl, vals = build()
        return np.asarray(wl, np.float64), np.asarray(vals, np.float64)

    return cached(cache_file("spectra", f"{kind}-{key}.npz"), made, load=load, save=save, check=problem)


def _colour_sd_build(kind: str, name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(wavelengths nm, values) of a colour-science dataset, over the full 360-830 nm range
    where a generating function exists: illuminant A is Planck's law at 2856 K
    (`colour.sd_CIE_standard_illuminant_A`, CIE 015:2018 Eq. 4.1), the D series as above. The
    tabulated A and D65 stop at 780 nm, where the IMX253 QE is still 0.21 (0.14 at 830 nm);
    zero-filling them made A 11 % and D65 3.4 % too dim to this sensor."""
    import colour  # heavy import, only when needed

    if kind == "cie":
        table = colour.SDS_ILLUMINANTS
    else:
        table = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    if name not in table:
        raise SpectrumError(f"unknown {kind} spectrum {name!r}; known: {sorted(table)}")
    if kind == "cie" and name == "A":
        sd = colour.sd_CIE_standard_illuminant_A(colour.SpectralShape(300, 830, 5))
        return tuple(map(float, sd.wavelengths)), tuple(map(float, sd.values))
    sd = table[name]
    wl, vals = np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)
    if kind == "cie" and name in _D_SERIES and wl.max() < WAVELENGTH_MAX_NM:
        xy = colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"][name]
        gen = colour.sd_CIE_illuminant_D_series(xy)
        tail = np.arange(wl.max() + WAVELENGTH_STEP_NM, WAVELENGTH_MAX_NM + 0.5, WAVELENGTH_STEP_NM)
        scale = vals[-1] / float(gen[wl.max()])
        wl = np.concatenate([wl, tail])
        vals = np.concatenate([vals, scale * np.asarray(gen[tail], float)])
    return tuple(map(float, wl)), tuple(map(float, vals))


def table_range_nm(source) -> tuple[float, float] | None:
    """Wavelength range (nm) a tabulated source covers (None: flat or generated everywhere)."""
    if not isinstance(source, str) or ":" not in source:
        return None
    kind, name = source.split(":", 1)
    if kind in ("cie", "colorchecker"):
        wl, _ = _colour_sd(kind, name)
        return float(min(wl)), float(max(wl))
    if kind == "file":
        path = Path(name) if Path(name).is_absolute() else ASSETS_DIR / name
        wl, _ = read_table(path)
        return float(wl.min()), float(wl.max())
    return None


def coverage_note(name: str, source, response: np.ndarray, threshold: float = 0.01) -> str | None:
    """A note when an emission table ends inside the sensor's response (response >= threshold x
    its peak): the emission is taken as zero beyond the table; the note estimates the share of
    the signal a flat continuation of the table's edge values would add there."""
    rng = table_range_nm(source)
    if rng is None:
        return None
    support = WAVELENGTHS_NM[response >= threshold * response.max()]
    lo, hi = rng
    if lo <= support.min() + 1e-9 and hi >= support.max() - 1e-9:
        return None
    shape = load_spectrum(source, emissive=True)
    inside = (WAVELENGTHS_NM >= lo) & (WAVELENGTHS_NM <= hi)
    flat = np.where(WAVELENGTHS_NM > hi, shape[inside][-1], np.where(WAVELENGTHS_NM < lo, shape[inside][0], 0.0))
    total = integrate(response * shape)
    missing = integrate(response * flat) / total if total > 0 else math.inf
    return (f"spectra.{name}: {source} is tabulated over {lo:g}-{hi:g} nm but the sensor responds "
            f"over {support.min():g}-{support.max():g} nm; emission outside the table is taken as zero "
            f"(a flat continuation would add about {missing:.1%} of this emitter's signal)")


def read_table(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a two-column CSV (wavelength_nm, value) with optional header and # comments."""
    rows, lines = [], []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise SpectrumError(f"{path}: not a readable text file ({type(e).__name__})") from None
    for line_no, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = [p.strip() for p in line.split(",")]
        try:
            rows.append((float(parts[0]), float(parts[1])))
            lines.append(line_no)
        except (ValueError, IndexError):
            if rows:  # a header is only allowed before the data
                raise SpectrumError(f"{path}:{line_no}: expected 'wavelength_nm,value'") from None
    if len(rows) < 2:
        raise SpectrumError(f"{path}: needs at least two rows of data")
    arr = np.asarray(rows, dtype=np.float64)
    if not np.all(np.isfinite(arr)) or np.any(arr[:, 1] < 0):
        raise SpectrumError(f"{path}: values must be finite and non-negative")
    # a table out of order or with a repeated wavelength is a broken file, not one to guess at
    step = np.diff(arr[:, 0])
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise SpectrumError(f"{path}:{lines[i]}: wavelength {arr[i, 0]:g} nm after {arr[i - 1, 0]:g} nm: "
                            "wavelengths must increase strictly (no repeats, no reordering)")
    return arr[:, 0], arr[:, 1]


def load_spectrum(source: str | float, *, emissive: bool) -> np.ndarray:
    """Resolve a spectrum source (table above) to values on `WAVELENGTHS_NM`.

    emissive: True for SPDs and QE (zero outside the table), False for reflectances (edges held).
    Returns float64 values, unitless shape (absolute scale is applied by the caller).
    """
    if isinstance(source, (int, float)) and not isinstance(source, bool):
        value = float(source)
        if not math.isfinite(value) or value < 0:
            raise SpectrumError(f"spectrum value must be finite and >= 0, got {source!r}")
        return np.full(WAVELENGTHS_NM.shape, value)
    if not isinstance(source, str) or ":" not in source:
        raise SpectrumError(f"spectrum source must look like 'cie:A', 'colorchecker:<patch>', "
                            f"'file:<path>' or 'neutral:<value>', got {source!r}")
    kind, name = source.split(":", 1)
    if kind in ("cie", "colorchecker"):
        wl, vals = _colour_sd(kind, name)
        return _on_grid(np.array(wl), np.array(vals), hold_edges=not emissive)
    if kind == "file":
        path = Path(name)
        if not path.is_absolute():
            path = ASSETS_DIR / path
        if not path.is_file():
            raise SpectrumError(f"spectrum file not found: {path}")
        wl, vals = read_table(path)
        return _on_grid(wl, vals, hold_edges=not emissive)
    if kind == "neutral":
        try:
            return load_spectrum(float(name), emissive=emissive)
        except ValueError:
            raise SpectrumError(f"bad neutral value in {source!r}") from None
    raise SpectrumError(f"unknown spectrum kind {kind!r} in {source!r}")


def integrate(values: np.ndarray) -> float:
    """Integral over the grid (trapezoid rule), in value x nm."""
    return float(np.trapezoid(values, WAVELENGTHS_NM))


@functools.lru_cache(maxsize=1)
def photopic_v() -> np.ndarray:
    """CIE 1924 photopic luminous efficiency V(lambda) on the grid (colour-science dataset, kept
    in the package cache: `_colour_dataset`)."""
    name = "CIE 1924 Photopic Standard Observer"

    def build():
        import colour

        sd = colour.colorimetry.SDS_LEFS_PHOTOPIC[name]
        return np.asarray(sd.wavelengths, float), np.asarray(sd.values, float)

    wl, vals = _colour_dataset("lef", name, build)
    return _on_grid(wl, vals, hold_edges=False)


def scale_to_photometric(shape: np.ndarray, photometric_value: float) -> np.ndarray:
    """Scale a relative SPD so that K_m * integral(V * spd) equals `photometric_value`.

    Gives W sr-1 nm-1 for candela, W m-2 sr-1 nm-1 for cd m-2, W m-2 nm-1 for lux.
    """
    luminous = LUMINOUS_EFFICACY_MAX_LM_PER_W * integrate(photopic_v() * shape)
    if luminous <= 0:
        raise SpectrumError("spectrum has no visible power: cannot scale to a photometric value")
    return shape * (photometric_value / luminous)


def sensor_response_e_per_J(qe: np.ndarray) -> np.ndarray:
    """Photo-electrons per joule of incident energy at each wavelength: QE * lambda / (h c).

    Integrating this against a spectral radiance (W m-2 sr-1 nm-1) over nm gives the
    sensor-weighted photon radiance in e- s-1 m-2 sr-1 (DESIGN.md, physics conventions).
    """
    return qe * photons_per_joule(WAVELENGTHS_NM)


def to_mitsuba(values: np.ndarray) -> str:
    """Mitsuba XML spectrum string 'lambda:value, ...' (irregular spectrum)."""
    return ", ".join(f"{w:g}:{v:.7g}" for w, v in zip(WAVELENGTHS_NM, values))


def is_neutral(values: np.ndarray, rtol: float = 1e-6) -> bool:
    """True when a spectrum is flat over the grid (within `rtol` of its mean)."""
    m = float(np.mean(values))
    return bool(np.all(np.abs(values - m) <= rtol * max(abs(m), 1e-300)))


def normalised_shape(values: np.ndarray) -> np.ndarray:
    """Spectrum divided by its integral (zero stays zero)."""
    s = integrate(values)
    return values / s if s > 0 else values
