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

from .units import LUMINOUS_EFFICACY_MAX_LM_PER_W, photons_per_joule
from .user_error import UserError

#: Rendering grid (nm): Mitsuba's spectral range is 360-830 nm.
WAVELENGTH_MIN_NM = 360.0
WAVELENGTH_MAX_NM = 830.0
WAVELENGTH_STEP_NM = 5.0
WAVELENGTHS_NM = np.arange(WAVELENGTH_MIN_NM, WAVELENGTH_MAX_NM + 0.5 * WAVELENGTH_STEP_NM,
                           WAVELENGTH_STEP_NM)

ASSETS_DIR = Path(__file__).resolve().parent.parent / "assets"


class SpectrumError(UserError):
    """A spectrum source that cannot be resolved."""


def _on_grid(wl_nm: np.ndarray, values: np.ndarray, *, hold_edges: bool) -> np.ndarray:
    order = np.argsort(wl_nm)
    wl_nm, values = wl_nm[order], values[order]
    if hold_edges:
        return np.interp(WAVELENGTHS_NM, wl_nm, values)
    return np.interp(WAVELENGTHS_NM, wl_nm, values, left=0.0, right=0.0)


@functools.lru_cache(maxsize=64)
def _colour_sd(kind: str, name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    import colour  # heavy import, only when needed

    if kind == "cie":
        table = colour.SDS_ILLUMINANTS
    else:
        table = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]
    if name not in table:
        raise SpectrumError(f"unknown {kind} spectrum {name!r}; known: {sorted(table)}")
    sd = table[name]
    return tuple(map(float, sd.wavelengths)), tuple(map(float, sd.values))


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
    """CIE 1924 photopic luminous efficiency V(lambda) on the grid (colour-science dataset)."""
    import colour

    sd = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    return _on_grid(np.asarray(sd.wavelengths, float), np.asarray(sd.values, float), hold_edges=False)


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
