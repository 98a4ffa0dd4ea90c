"""core/cache.py (issue 30: one place for the content-keyed caches): load-or-build with atomic
writes, and each user's key still the recipe it had, so cache files written before stay valid."""

from __future__ import annotations

import dataclasses
import hashlib
import json

import numpy as np
import pytest

from poevp_optics.core.cache import cache_file, cached, digest, json_digest


def test_digest_is_the_hash_prefix():
    assert digest("abc") == hashlib.sha1(b"abc").hexdigest()[:16]
    assert digest(b"abc", algo="sha256", length=32) == hashlib.sha256(b"abc").hexdigest()[:32]
    obj = {"b": [1, 2.5, "v1"], "a": None}
    assert json_digest(obj, sort_keys=True) == hashlib.sha1(json.dumps(obj, sort_keys=True).encode()).hexdigest()[:16]


def _save_npy(path, value):
    with open(path, "wb") as fh:
        np.save(fh, value)


def test_cached_builds_once_then_loads(tmp_path):
    calls = []

    def build():
        calls.append(1)
        return np.arange(5.0)

    path = tmp_path / "sub" / "x.npy"
    a = cached(path, build, load=np.load, save=_save_npy)
    b = cached(path, build, load=np.load, save=_save_npy)
    assert len(calls) == 1 and path.is_file()
    np.testing.assert_array_equal(a, b)


def test_an_unreadable_file_is_rebuilt_with_a_note(tmp_path, capsys):
    from poevp_optics.core.cache import write_checksum

    path = tmp_path / "x.npy"
    path.write_bytes(b"not an npy file")
    write_checksum(path)                          # its checksum matches: only the load fails

    out = cached(path, lambda: np.ones(2), load=np.load, save=_save_npy)
    np.testing.assert_array_equal(out, np.ones(2))
    np.testing.assert_array_equal(np.load(path), np.ones(2))
    assert f"poevp: cache file {path} failed its check" in capsys.readouterr().err


def test_a_failed_write_leaves_nothing(tmp_path):
    def save(p, v):
        p.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError):
        cached(tmp_path / "x.bin", lambda: 1, load=lambda p: p.read_bytes(), save=save)
    assert list(tmp_path.iterdir()) == []


def test_cache_file_is_under_the_cache_root(tmp_path, monkeypatch):
    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    assert cache_file("plates", "p.png") == tmp_path / "plates" / "p.png"


def test_the_users_keep_their_key_recipes(tmp_path, monkeypatch):
    """Plates (text, size, format, band, version), car mesh and the objective's PSF grid: the file names are the hashes they were
    (recomputed here with hashlib from each recipe)."""
    from poevp_optics.camera import objective as ob
    from poevp_optics.core import spectra
    from poevp_optics.sources.plates import PLATE_FONT, cached_plate_path
    from poevp_optics.sources.road import MESH_VERSION, cached_car_mesh, car_rear_mesh

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    plate = cached_plate_path("AB 123", 104, 22)
    font = hashlib.sha256(PLATE_FONT.read_bytes()).hexdigest()[:16]
    assert plate == tmp_path / "plates" / f"plate_{hashlib.sha1(f'AB 123|104|22|eu|0|{font}|v2'.encode()).hexdigest()[:16]}.png"
    assert plate.is_file()
    verts, tris = car_rear_mesh()
    key = hashlib.sha1(verts.tobytes() + tris.tobytes() + str(MESH_VERSION).encode()).hexdigest()[:16]
    assert cached_car_mesh() == tmp_path / "meshes" / f"car_rear_{key}.ply"

    from importlib.metadata import version

    p = ob.ObjectiveParams(psf="prescription", f_number=8.0)
    keys = ("prescription", "f_number", "qe")
    qe = np.ascontiguousarray(spectra.load_spectrum(p.qe, emissive=True)).tobytes()
    blob = json.dumps({"kind": "psf_grid", "v": ob.CACHE_VERSION, "optiland": version("optiland"),
                       "shape": [40, 50], "params": {k: dataclasses.asdict(p)[k] for k in keys},
                       "qe": hashlib.sha256(qe).hexdigest()}, sort_keys=True)
    assert ob.cache_key("psf_grid", p, (40, 50), keys) == hashlib.sha256(blob.encode()).hexdigest()[:32]
