"""Dry asphalt texture: procedural, seeded albedo and roughness maps of a dense asphalt surface,
written as 16-bit PNG through the verified cache (core/cache.py).

| parameter         | type  | unit | default | meaning |
|-------------------|-------|------|---------|---------|
| albedo            | float | 1    | 0.09    | the albedo map's mean (hemispherical reflectance of the dry surface) |
| roughness         | float | 1    | 0.8     | the roughness map's mean (Mitsuba `principled` roughness) |
| tile_m            | float | m    | 2.0     | the side of the square the map covers (it tiles the road) |
| seed              | int   | -    | 0       | the draw of the pattern |

Albedo. New dense asphalt reflects 0.05-0.10 of sunlight and aged, lighter asphalt 0.10-0.18
(US EPA, "Reducing Urban Heat Islands: Compendium of Strategies - Cool Pavements", 2008, Table 1,
after Pomerantz et al., LBNL); CIE 144's R3 road class, which the street-light files are
designed with (scripts/make_street_lamp_files.py), has an average luminance coefficient q0 = 0.07
sr-1 (q0 pi ~ 0.22 for a diffuse equivalent at the road's lighting angles; q0 is not an albedo).
The default 0.09 is a mid-life asphalt in the EPA range.

Pattern (ours, a statistical model, not a measured surface): the binder (dark, smooth) and the
aggregate's exposed stone chips (lighter, rougher), at PX_PER_M pixels per metre:

  * a field f = 1 + 0.12 g_1 + 0.06 g_2 with g_k unit-variance Gaussian noise low-passed at 0.25 m
    and 0.02 m (blotches of binder wear, grain);
  * chips: a Boolean model of 8 mm discs (Poisson centres), 35 % expected area cover (a dense
    asphalt's surface aggregate, EN 13108-1 AC 11: 11 mm top size), each 1.6 x the binder's
    albedo and (1 + 0.15 / roughness) x its roughness;
  * the albedo map is f x chips scaled so that its mean is `albedo` exactly (then clipped to
    [0, 1] and rescaled until the mean holds to 1e-6), stored as round(65535 a); the roughness
    map is (2 - f) x chips (worn, lighter binder is smoother) scaled likewise to its mean, clipped
    to [0.05, 1].

Both maps wrap (the noise is periodic: FFT filtering), so a road tiled with them has no seams.
Read them with `<texture type="bitmap">` and `<boolean name="raw" value="true"/>` (linear values,
no sRGB decoding).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Map resolution (px per m) and size limits.
PX_PER_M = 256
CHIP_DIAMETER_M, CHIP_COVER, CHIP_GAIN, CHIP_ROUGHER = 0.008, 0.35, 1.6, 0.15
NOISE_M = ((0.25, 0.12), (0.02, 0.06))           # (low-pass length, amplitude) per octave
VERSION = 1


def _periodic_noise(n: int, length_px: float, rng) -> np.ndarray:
    """Unit-variance Gaussian noise low-passed by a Gaussian of sigma length_px (periodic)."""
    w = rng.standard_normal((n, n))
    k = np.fft.fftfreq(n)
    g = np.exp(-2 * (np.pi * length_px) ** 2 * (k[:, None] ** 2 + k[None, :] ** 2))
    out = np.real(np.fft.ifft2(np.fft.fft2(w) * g))
    return out / out.std()


def _chips(n: int, rng) -> np.ndarray:
    """Boolean mask of the stone chips: a Boolean model of discs (Poisson centres, periodic), its
    intensity set so that the expected cover 1 - exp(-lambda A_disc) is CHIP_COVER."""
    r = CHIP_DIAMETER_M * PX_PER_M / 2
    yy, xx = np.mgrid[-int(r) - 1:int(r) + 2, -int(r) - 1:int(r) + 2]
    disc = (yy ** 2 + xx ** 2) <= r * r
    count = rng.poisson(-np.log(1 - CHIP_COVER) * n * n / disc.sum())
    cy, cx = rng.integers(0, n, count), rng.integers(0, n, count)
    mask = np.zeros((n, n), bool)
    for dy, dx in zip(yy[disc], xx[disc]):
        mask[(cy + dy) % n, (cx + dx) % n] = True
    return mask


def _scale_to_mean(m: np.ndarray, mean: float, lo: float, hi: float) -> np.ndarray:
    """m scaled about its mean to `mean`, clipped to [lo, hi], repeated until the mean holds."""
    for _ in range(50):
        m = np.clip(m * (mean / m.mean()), lo, hi)
        if abs(m.mean() - mean) < 1e-7:
            break
    return m


def asphalt_maps(albedo: float = 0.09, roughness: float = 0.8, tile_m: float = 2.0,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(albedo, roughness) maps as uint16 (n, n), n = tile_m x PX_PER_M (module docstring)."""
    if not 0 < albedo < 1 or not 0.05 <= roughness <= 1 or not 0.25 <= tile_m <= 16:
        raise ValueError(f"asphalt: albedo {albedo} must be in (0, 1), roughness {roughness} in [0.05, 1], "
                         f"tile_m {tile_m} in [0.25, 16] m")
    n = int(round(tile_m * PX_PER_M))
    rng = np.random.default_rng(seed)
    f = 1.0 + sum(a * _periodic_noise(n, length_m * PX_PER_M, rng) for length_m, a in NOISE_M)
    chips = _chips(n, rng)
    a = _scale_to_mean(np.maximum(f, 0.05) * np.where(chips, CHIP_GAIN, 1.0), albedo, 0.0, 1.0)
    r = _scale_to_mean((2.0 - f) * np.where(chips, 1.0 + CHIP_ROUGHER / roughness, 1.0), roughness, 0.05, 1.0)
    return (np.round(a * 65535).astype(np.uint16), np.round(r * 65535).astype(np.uint16))


def cached_asphalt_maps(albedo: float = 0.09, roughness: float = 0.8, tile_m: float = 2.0,
                        seed: int = 0) -> tuple[Path, Path]:
    """The two maps' PNG paths in the cache (checksum and every pixel checked before use)."""
    from poevp_optics.core.cache import cache_file, cached_path, digest
    from poevp_optics.core.io import read_png, write_png

    maps = asphalt_maps(albedo, roughness, tile_m, seed)
    key = digest(f"{albedo:.9g}|{roughness:.9g}|{tile_m:.9g}|{seed}|{PX_PER_M}|v{VERSION}")
    out = []
    for name, img in zip(("albedo", "roughness"), maps):
        def problem(p: Path, img=img) -> str | None:
            got = read_png(p)
            if got.shape != img.shape or got.dtype != img.dtype:
                return f"{got.dtype} image of shape {got.shape}, not uint16 {img.shape}"
            return None if np.array_equal(got, img) else "pixels differ from the asphalt map"

        path = cache_file("textures", f"asphalt_{name}_{key}.png")
        out.append(cached_path(path, lambda tmp, img=img: write_png(tmp, img), problem))
    return out[0], out[1]
