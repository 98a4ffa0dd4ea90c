"""Spectra, photometry, trajectories, overrides, EXR/PNG I/O, atomic output folders."""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.sources import spectra
from poevp_optics.core.io import MARKER, _umask, read_exr, read_png, staged_dir, write_exr, write_png
from poevp_optics.sources.plates import plate_texture
from poevp_optics.sources.motion import MotionSpec
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import apply_overrides, parse_override
from poevp_optics.core.units import PLANCK_J_S, SPEED_OF_LIGHT_M_PER_S, photons_per_joule


def test_photometric_scaling_round_trips():
    shape = spectra.load_spectrum("cie:LED-B4", emissive=True)
    spd = spectra.scale_to_photometric(shape, 120000.0)               # W sr-1 nm-1
    cd = 683.002 * spectra.integrate(spectra.photopic_v() * spd)
    assert cd == pytest.approx(120000.0, rel=1e-12)
    # Illuminant A is Planck's law at 2856 K (CIE 015: 2848 K with the old c2 = 1.435e-2 m K,
    # i.e. 2856 K with c2 = 1.4388e-2 m K, equal to 1.5e-4 in c2/T) over the whole 360-830 nm
    # grid (not zero beyond colour-science's 780 nm table): its luminous efficacy within the
    # grid agrees with Planck's law written out here to that 1.5e-4 (rel 1e-3 allowed).
    a = spectra.scale_to_photometric(spectra.load_spectrum("cie:A", emissive=True), 1.0)
    wl_m = spectra.WAVELENGTHS_NM * 1e-9
    planck = wl_m ** -5 / np.expm1(1.4388e-2 / (wl_m * 2856.0))
    efficacy = 683.002 * np.trapezoid(spectra.photopic_v() * planck, wl_m) / np.trapezoid(planck, wl_m)
    assert 1 / spectra.integrate(a) == pytest.approx(efficacy, rel=1e-3)


def test_photon_energy():
    # one joule at 500 nm is 500e-9 / (h c) photons ~ 2.517e18
    assert photons_per_joule(500.0) == pytest.approx(500e-9 / (PLANCK_J_S * SPEED_OF_LIGHT_M_PER_S))
    assert photons_per_joule(500.0) == pytest.approx(2.5170e18, rel=1e-4)


def test_spectrum_sources_and_errors(tmp_path):
    flat = spectra.load_spectrum("neutral:0.3", emissive=False)
    assert spectra.is_neutral(flat) and flat[0] == 0.3
    white = spectra.load_spectrum("colorchecker:white 9.5 (.05 D)", emissive=False)
    assert 0.8 < white.max() < 0.95 and not spectra.is_neutral(white)
    led = spectra.load_spectrum("cie:LED-B4", emissive=True)
    assert led[0] == 0 and led[-1] == 0             # zero outside 380-780 nm
    f = tmp_path / "s.csv"
    f.write_text("wavelength_nm,v\n400,1\n700,2\n")
    vals = spectra.load_spectrum(f"file:{f}", emissive=True)
    assert vals[spectra.WAVELENGTHS_NM == 550][0] == pytest.approx(1.5)
    assert vals[0] == 0.0
    for bad in ("cie:nope", "file:/no/such.csv", "what", "neutral:x", -1.0):
        with pytest.raises(spectra.SpectrumError):
            spectra.load_spectrum(bad, emissive=True)


def test_trajectories():
    lin = MotionSpec(kind="linear", start_offset_m=(1, 0, 0), velocity_m_per_s=(2, 0, -1))
    np.testing.assert_allclose(lin.offset_m(0.5), [2, 0, -0.5])
    assert not lin.is_static
    key = MotionSpec(kind="keyframes", times_s=(0.0, 1.0), offsets_m=((0, 0, 0), (1, 2, 3)))
    np.testing.assert_allclose(key.offset_m(0.25), [0.25, 0.5, 0.75])
    np.testing.assert_allclose(key.offset_m(5.0), [1, 2, 3])          # held after the last key
    assert MotionSpec(kind="linear").is_static


def test_overrides():
    assert parse_override("render.spp=64") == (["render", "spp"], 64)
    assert parse_override('predictor.name="oracle"') == (["predictor", "name"], "oracle")
    assert parse_override("predictor.name=flow") == (["predictor", "name"], "flow")
    assert parse_override("render.resolution=[8, 16]") == (["render", "resolution"], [8, 16])
    raw = apply_overrides({"render": {"spp": 1}}, ["render.spp=4", "dmd.registration.scale=2.0"])
    assert raw == {"render": {"spp": 4}, "dmd": {"registration": {"scale": 2.0}}}
    with pytest.raises(SceneError):
        parse_override("spp=4")


def test_exr_keeps_float32_above_half_range(tmp_path):
    img = np.array([[1e-3, 7e4], [1e20, 3.0e38]], dtype=np.float32)     # 65504 = half max
    write_exr(tmp_path / "a.exr", {"Y": img}, {"poevp_unit": "e- s-1 m-2 sr-1"})
    chans, header = read_exr(tmp_path / "a.exr")
    np.testing.assert_array_equal(chans["Y"], img)
    assert header["poevp_unit"] == "e- s-1 m-2 sr-1"
    with pytest.raises(ValueError, match="NaN or Inf"):
        write_exr(tmp_path / "b.exr", {"Y": np.array([[np.nan]])})
    assert not (tmp_path / "b.exr").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["a.exr"]           # no temp files left


def test_png_roundtrip_16bit(tmp_path):
    img = (np.arange(12, dtype=np.uint16) * 5000).reshape(3, 4)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_png(tmp_path / "a.png"), img)


def test_staged_dir_replaces_whole_or_nothing(tmp_path):
    out = tmp_path / "out"
    with staged_dir(out, kind="render") as s:
        (s / "a.txt").write_text("1")
    with pytest.raises(RuntimeError):
        with staged_dir(out, kind="render") as s:
            (s / "b.txt").write_text("2")
            raise RuntimeError("boom")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "a.txt"]
    with staged_dir(out, kind="render") as s:
        (s / "c.txt").write_text("3")
    assert sorted(p.name for p in out.iterdir()) == [MARKER, "c.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]     # no lock, no staging left
    assert (out.stat().st_mode & 0o777) == 0o777 & ~_umask()           # not mkdtemp's 0700


def test_plate_texture_has_ink_and_sheeting():
    tex = plate_texture("AB 123", 520, 110)
    assert tex.shape == (110, 520) and tex.dtype == np.uint8
    ink = np.mean(tex < 64)
    assert 0.08 < ink < 0.45                       # characters + border cover part of the plate
    assert np.mean(tex > 240) > 0.4
    with pytest.raises(ValueError):
        plate_texture("  ")
