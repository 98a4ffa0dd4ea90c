"""colour-science's tables kept in the package cache: the same numbers, and no colour import."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np

from ..conftest import ROOT

#: A fresh process reads every dataset kind a scene can name, then reports whether colour loaded.
_READ = """
import json, sys
from poevp_optics.core import spectra
out = {s: spectra.load_spectrum(s, emissive=e).tolist()
       for s, e in (("cie:A", True), ("cie:D65", True), ("colorchecker:dark skin", False))}
out["V"] = spectra.photopic_v().tolist()
print(json.dumps({"colour_loaded": "colour" in sys.modules, "spectra": out}))
"""


def _read(cache) -> dict:
    import json

    env = {**os.environ, "POEVP_CACHE_DIR": str(cache), "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-c", _READ], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    return {**json.loads(r.stdout), "stderr": r.stderr}


def test_cached_tables_are_colour_sciences_and_a_warm_cache_needs_no_colour(tmp_path):
    """A cold cache imports colour and fills spectra/; a warm one gives the same float64 values
    without importing it; both equal colour-science's own tables, read here directly (V(lambda)
    on the grid by np.interp, zero outside the table)."""
    import colour

    cold = _read(tmp_path)
    assert cold["colour_loaded"] and len(list((tmp_path / "spectra").glob("*.npz"))) == 4
    warm = _read(tmp_path)
    assert not warm["colour_loaded"]
    assert warm["spectra"] == cold["spectra"]
    sd = colour.colorimetry.SDS_LEFS_PHOTOPIC["CIE 1924 Photopic Standard Observer"]
    grid = np.arange(360.0, 830.0 + 2.5, 5.0)
    v = np.interp(grid, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float), left=0.0, right=0.0)
    assert np.array_equal(np.asarray(warm["spectra"]["V"]), v)
    patch = colour.SDS_COLOURCHECKERS["ColorChecker N Ohta"]["dark skin"]
    refl = np.interp(grid, np.asarray(patch.wavelengths, float), np.asarray(patch.values, float))
    assert np.array_equal(np.asarray(warm["spectra"]["colorchecker:dark skin"]), refl)


def test_a_damaged_table_is_rebuilt_to_the_same_values(tmp_path):
    """A spectra file overwritten with another table fails its checksum and is rebuilt (one note
    on stderr); the values read are colour-science's again."""
    first = _read(tmp_path)
    victim = sorted((tmp_path / "spectra").glob("lef-*.npz"))[0]
    with open(victim, "wb") as fh:
        np.savez(fh, wavelengths_nm=np.arange(3.0), values=np.ones(3))
    again = _read(tmp_path)
    assert again["spectra"] == first["spectra"] and again["colour_loaded"]
    assert again["stderr"].count("failed its check") == 1 and victim.name in again["stderr"]
