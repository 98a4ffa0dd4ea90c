"""Every on-disk cache verifies its file on load and rebuilds it when it does not pass (core/cache.py):
a cut-short, emptied, overwritten or foreign file, or one written before files carried checksums,
is removed and rebuilt with one note line on stderr, never an error; an intact file is not rebuilt.

Unit tests damage each cache kind in turn and call its user directly (builds replaced by fast,
deterministic stand-ins where the real one takes seconds); the end-to-end tests damage the cache
files a small night_road render reads (PSF grids, RI table, vehicle meshes, plate texture) and check the
run succeeds, notes it, and writes the same bytes as a run on a clean cache."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from poevp_optics.core import cache as cc
from poevp_optics.core.io import write_png
from tests.conftest import ROOT, SCENES


# ----------------------------------------------------------------------------- damages
def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])


def _empty(path: Path) -> None:
    path.write_bytes(b"")


def _random_bytes(path: Path) -> None:
    n = max(path.stat().st_size, 64)
    path.write_bytes(np.random.default_rng(7).integers(0, 256, n, dtype=np.uint8).tobytes())


def _drop_checksum(path: Path) -> None:
    """A file written before cache files carried checksums: rebuilt once, with no note."""
    cc.checksum_path(path).unlink()


BYTE_DAMAGES = {"truncated": _truncate, "empty": _empty, "random_bytes": _random_bytes,
                "no_checksum": _drop_checksum}


def _resigned(write):
    """A damage writing a well-formed file of other content with a matching checksum file: only
    the user's content check can tell."""
    def damage(path: Path) -> None:
        write(path)
        cc.write_checksum(path)
    return damage


def _note_lines(err: str, path: Path) -> list[str]:
    return [ln for ln in err.splitlines()
            if ln.startswith(f"poevp: cache file {path} failed its check (") and ln.endswith("); rebuilt")]


def _assert_healed(capsys, path: Path, clean: bytes, builds: list, n_builds: int, damage: str = "") -> None:
    """One note naming `path` (none for a file that had no checksum file: nothing was damaged), one
    more build, and the file as clean again with a valid checksum."""
    err = capsys.readouterr().err
    assert len(_note_lines(err, path)) == (0 if damage == "no_checksum" else 1), err
    assert "failed its check" not in err or damage != "no_checksum", err
    assert len(builds) == n_builds
    assert path.read_bytes() == clean and cc.checksum_problem(path) is None
    assert not list(path.parent.glob(".*.lock")) and not list(path.parent.glob("*.tmp*"))


# ----------------------------------------------------------------------------- core/cache.py
def _save_npy(tmp, value):
    with open(tmp, "wb") as fh:
        np.save(fh, value)


def _npy_check(v):
    return None if v.shape == (5,) and v.dtype == np.float64 else f"{v.dtype} {v.shape}"


CORE_DAMAGES = {**BYTE_DAMAGES,
                "other_array": _resigned(lambda p: _save_npy(p, np.zeros((2, 3), np.float32))),
                "foreign_checksum_line": lambda p: cc.checksum_path(p).write_text("sha256 0 0 other\n")}


@pytest.mark.parametrize("damage", CORE_DAMAGES)
def test_cached_rebuilds_a_damaged_file_with_a_note(tmp_path, capsys, damage):
    builds = []

    def build():
        builds.append(1)
        return np.arange(5.0)

    path = tmp_path / "x.npy"
    cc.cached(path, build, load=np.load, save=_save_npy, check=_npy_check)
    clean = path.read_bytes()
    CORE_DAMAGES[damage](path)
    out = cc.cached(path, build, load=np.load, save=_save_npy, check=_npy_check)
    np.testing.assert_array_equal(out, np.arange(5.0))
    _assert_healed(capsys, path, clean, builds, 2, damage)
    cc.cached(path, build, load=np.load, save=_save_npy, check=_npy_check)      # healed: read, not built
    assert len(builds) == 2 and not capsys.readouterr().err


def test_an_intact_file_is_loaded_and_not_built(tmp_path, capsys):
    path = tmp_path / "x.npy"
    cc.cached(path, lambda: np.arange(5.0), load=np.load, save=_save_npy, check=_npy_check)
    line = cc.checksum_path(path).read_text().split()
    assert line[0] == cc.CHECKSUM_TAG and line[2] == str(path.stat().st_size) and line[3] == path.name
    import hashlib

    assert line[1] == hashlib.sha256(path.read_bytes()).hexdigest()

    def build():
        raise AssertionError("built although the file is intact")

    np.testing.assert_array_equal(cc.cached(path, build, load=np.load, save=_save_npy, check=_npy_check),
                                  np.arange(5.0))
    assert not capsys.readouterr().err


def test_a_new_file_and_an_orphan_checksum_are_built_without_a_note(tmp_path, capsys):
    path = tmp_path / "sub" / "x.npy"
    cc.cached(path, lambda: np.arange(5.0), load=np.load, save=_save_npy)
    path.unlink()                                     # the checksum file stays, its file gone
    cc.cached(path, lambda: np.arange(5.0), load=np.load, save=_save_npy)
    assert cc.checksum_problem(path) is None and not capsys.readouterr().err


def test_a_check_that_raises_counts_as_a_failure(tmp_path, capsys):
    path = tmp_path / "x.npy"
    cc.cached(path, lambda: np.arange(5.0), load=np.load, save=_save_npy)

    def check(v):
        if v.size == 5 and not getattr(check, "built", False):
            raise KeyError("kernels")
        return None

    def build():
        check.built = True
        return np.arange(5.0)

    cc.cached(path, build, load=np.load, save=_save_npy, check=check)
    (line,) = _note_lines(capsys.readouterr().err, path)
    assert "KeyError" in line and "kernels" in line


def test_a_failed_rebuild_leaves_neither_file_nor_checksum(tmp_path, capsys):
    path = tmp_path / "x.npy"
    cc.cached(path, lambda: np.arange(5.0), load=np.load, save=_save_npy)
    _truncate(path)

    def build():
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        cc.cached(path, build, load=np.load, save=_save_npy)
    assert list(tmp_path.iterdir()) == [] and not capsys.readouterr().err


# ----------------------------------------------------------------------------- PSF grid, RI table
@pytest.fixture
def objective(monkeypatch):
    """ObjectiveParams, an image shape, and the prescription builds replaced by closed forms
    (a Gaussian per node, cos^4 relative illumination) counting their calls."""
    from poevp_optics.camera.objective import psfs, vignetting
    from poevp_optics.camera.objective.params import ObjectiveParams

    params = ObjectiveParams(psf="prescription", vignetting="prescription", f_number=8.0)
    builds = {"psf": [], "ri": []}

    def grid(p, shape):
        builds["psf"].append(tuple(shape))
        ys, xs = psfs.node_positions_px(p.field_samples, shape[0]), psfs.node_positions_px(p.field_samples, shape[1])
        r = np.arange(-2, 3)
        k = np.exp(-(r[:, None] ** 2 + r[None, :] ** 2) / 2.0)
        kern = np.broadcast_to(k / k.sum(), (ys.size, xs.size, 5, 5)).copy()
        return psfs.PSFGrid(f"prescription:{p.prescription}", ys, xs, kern, 1e-3, "", (int(shape[0]), int(shape[1])))

    def ri(p, tmax):
        builds["ri"].append(tmax)
        th = np.linspace(0.0, tmax, 129)
        return th, np.cos(th) ** 4

    monkeypatch.setattr(psfs, "_prescription_grid_build", grid)
    monkeypatch.setattr(vignetting, "ri_profile", ri)
    return params, (40, 50), builds


def _psf(params, shape, folder):
    from poevp_optics.camera.objective import psfs

    return psfs._prescription_grid(params, shape, cache_dir=folder)


def _other_grid(params):
    def write(path):
        from poevp_optics.camera.objective import psfs

        psfs._save_grid(path, psfs._prescription_grid_build(params, (41, 50)))
    return write


@pytest.mark.parametrize("damage", [*BYTE_DAMAGES, "other_arrays", "grid_of_another_image"])
def test_psf_grid_heals(tmp_path, capsys, objective, damage):
    from poevp_optics.core.cache import save_npz

    params, shape, builds = objective
    g0 = _psf(params, shape, tmp_path)
    (path,) = tmp_path.glob("psf-*.npz")
    clean = path.read_bytes()
    extra = {"other_arrays": _resigned(lambda p: save_npz(p, {"a": np.zeros(3), "image_shape": np.array([0, 0])})),
             "grid_of_another_image": _resigned(_other_grid(params))}
    (BYTE_DAMAGES | extra)[damage](path)
    n = len(builds["psf"])                            # (the other image's grid was built by the damage)
    g = _psf(params, shape, tmp_path)
    assert builds["psf"][-1] == shape
    _assert_healed(capsys, path, clean, builds["psf"], n + 1, damage)
    assert g.image_shape == g0.image_shape and np.array_equal(g.kernels, g0.kernels)


def test_an_intact_psf_grid_is_not_rebuilt(tmp_path, capsys, objective):
    params, shape, builds = objective
    _psf(params, shape, tmp_path)
    _psf(params, shape, tmp_path)
    assert builds["psf"] == [shape] and not capsys.readouterr().err


@pytest.mark.parametrize("damage", [*BYTE_DAMAGES, "table_of_another_field"])
def test_ri_table_heals(tmp_path, capsys, objective, damage):
    from poevp_optics.camera.objective import vignetting
    from poevp_optics.core.cache import save_npz

    params, shape, builds = objective
    ri0 = vignetting._ri_prescription(params, shape, tmp_path)
    (path,) = tmp_path.glob("ri-*.npz")
    clean = path.read_bytes()
    other = _resigned(lambda p: save_npz(p, {"theta_rad": np.linspace(0, 0.5, 129), "ri": np.ones(129)}))
    (BYTE_DAMAGES | {"table_of_another_field": other})[damage](path)
    ri = vignetting._ri_prescription(params, shape, tmp_path)
    _assert_healed(capsys, path, clean, builds["ri"], 2, damage)
    np.testing.assert_array_equal(ri, ri0)
    vignetting._ri_prescription(params, shape, tmp_path)
    assert len(builds["ri"]) == 2


# ----------------------------------------------------------------------------- car mesh, plate texture
@pytest.fixture
def road(tmp_path, monkeypatch):
    """sources.road with the cache in tmp_path and write_ply's calls counted."""
    from poevp_optics.sources import road as rd

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    writes, real = [], rd.write_ply

    def counted(*a):
        writes.append(1)
        real(*a)

    monkeypatch.setattr(rd, "write_ply", counted)
    return rd, writes


def _other_mesh(path):
    from poevp_optics.sources.road import car_rear_mesh, write_ply

    v, t = car_rear_mesh()
    write_ply(path, v * np.float32(1.5), t)          # the same counts and header, another car


@pytest.mark.parametrize("damage", [*BYTE_DAMAGES, "ply_of_another_mesh", "ply_with_a_face_less"])
def test_car_mesh_heals_before_mitsuba_reads_it(road, capsys, damage):
    from poevp_optics.sources.road import car_rear_mesh, write_ply

    rd, writes = road
    path = rd.cached_car_mesh()
    clean = path.read_bytes()
    v, t = car_rear_mesh()
    extra = {"ply_of_another_mesh": _resigned(_other_mesh),
             "ply_with_a_face_less": _resigned(lambda p: write_ply(p, v, t[:-1]))}
    (BYTE_DAMAGES | extra)[damage](path)
    n = len(writes)                                   # (a damage may write a PLY itself)
    assert rd.cached_car_mesh() == path
    _assert_healed(capsys, path, clean, writes, n + 1, damage)
    import mitsuba as mi                              # the healed file as Mitsuba reads it: the car mesh

    from poevp_optics.core import runtime

    runtime.set_variant(runtime.choose_variant("mono")[0])
    m = mi.load_dict({"type": "ply", "filename": str(path)})
    np.testing.assert_allclose(np.array(m.vertex_positions_buffer()).reshape(-1, 3), v, rtol=0, atol=5e-7)
    np.testing.assert_array_equal(np.array(m.faces_buffer()).reshape(-1, 3), t)


def test_an_intact_car_mesh_is_not_rewritten(road, capsys):
    rd, writes = road
    rd.cached_car_mesh()
    rd.cached_car_mesh()
    assert writes == [1] and not capsys.readouterr().err


PLATE = ("NR 17 RA", 208, 44)


@pytest.mark.parametrize("damage", [*BYTE_DAMAGES, "png_of_another_size", "png_of_another_text"])
def test_plate_texture_heals_before_mitsuba_reads_it(tmp_path, monkeypatch, capsys, damage):
    import cv2

    from poevp_optics.core import io
    from poevp_optics.sources import plates

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    writes, real = [], io.write_png          # the cache writes a texture through core.io (cached_png)
    monkeypatch.setattr(io, "write_png", lambda *a: (writes.append(1), real(*a)))
    path = plates.cached_plate_path(*PLATE)
    clean = path.read_bytes()
    extra = {"png_of_another_size": _resigned(lambda p: write_png(p, plates.plate_texture(PLATE[0], 104, 22))),
             "png_of_another_text": _resigned(lambda p: write_png(p, plates.plate_texture("XY 99 ZZ", *PLATE[1:])))}
    (BYTE_DAMAGES | extra)[damage](path)
    assert plates.cached_plate_path(*PLATE) == path
    _assert_healed(capsys, path, clean, writes, 2, damage)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert img.shape == (PLATE[2], PLATE[1]) and np.array_equal(img, plates.plate_texture(*PLATE))
    plates.cached_plate_path(*PLATE)
    assert len(writes) == 2


# ----------------------------------------------------------------------------- training and evaluation data
def test_predictor_training_sequences_heal(tmp_path, monkeypatch, capsys):
    """predictor_data/seq_*.npz: the renders replaced by frames that encode their seed."""
    from poevp_optics.apps.train import training_data as tdm

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    renders = []

    def fake(overrides, frames, seed):
        renders.append(seed)
        return np.full((frames, 8, 12), seed % 251, np.uint8)

    monkeypatch.setattr(tdm, "render_ldr_sequence", fake)
    a = tdm.build_dataset(2, 3, seed=5, resolution=(8, 12), progress=False)
    (path,) = (tmp_path / "predictor_data").glob("seq_*.npz")
    clean = path.read_bytes()
    for k, damage in enumerate([_truncate, _resigned(lambda p: np.savez(p, frames=np.zeros((2, 3, 4, 4), np.uint8)))]):
        damage(path)
        b = tdm.build_dataset(2, 3, seed=5, resolution=(8, 12), progress=False)
        np.testing.assert_array_equal(a, b)
        _assert_healed(capsys, path, clean, renders, 2 * (k + 2))
    tdm.build_dataset(2, 3, seed=5, resolution=(8, 12), progress=False)
    assert len(renders) == 6 and not capsys.readouterr().err


def test_train_data_folder_heals(tmp_path, monkeypatch, capsys):
    """train_data/<scene>-<hash>/: a damaged split or a manifest of another data set is rendered
    again (renders replaced by frames that encode the sequence's seed; the scene's geometry real)."""
    from poevp_optics.apps.train import train_data as td

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    renders = []

    def fake(spec):
        renders.append(spec.render.seed)
        h, w = spec.render.resolution
        return (np.full((spec.timing.frames, h, w), spec.render.seed % 251, np.uint8),
                np.zeros((spec.timing.frames, 4), np.int32))

    monkeypatch.setattr(td, "render_frames", fake)
    cfg = td.DataConfig(sequences=(1, 1, 1), frames=4, resolution=(32, 56), spp=2)
    scene = str(SCENES / "highbeam_plate")
    d0 = td.build_data(scene, cfg, progress=False, log=lambda *_: None)
    clean = {s: (d0.folder / f"{s}.npz").read_bytes() for s in td.SPLITS}

    def other_manifest(p):
        m = json.loads(p.read_text())
        m["content_sha256"] = "0" * 64
        p.write_text(json.dumps(m))

    note = f"poevp: cache folder {d0.folder} failed its check ("
    for damage, said in ((_truncate, "val.npz: "), (_resigned(other_manifest), "manifest.json names data set 000000"),
                         (_drop_checksum, None)):
        damage(d0.folder / ("val.npz" if damage is _truncate else "manifest.json"))
        d = td.build_data(scene, cfg, progress=False, log=lambda *_: None)
        err = capsys.readouterr().err
        assert (note + said in err) if said else "failed its check" not in err, err
        assert d.rendered and all((d.folder / f"{s}.npz").read_bytes() == clean[s] for s in td.SPLITS)
        for s in td.SPLITS:
            np.testing.assert_array_equal(d.splits[s]["frames"], d0.splits[s]["frames"])
    assert len(renders) == 4 * 3
    assert not td.build_data(scene, cfg, progress=False, log=lambda *_: None).rendered


def test_evaluation_renders_heal(tmp_path, monkeypatch, capsys):
    """eval/*.npz: one tiny real sequence (highbeam_plate at 46x80, 2 frames, 2 spp): a truncated
    file and one with arrays of another image size are rendered again to the same exposures."""
    from poevp_optics.apps.evaluate.eval_sequences import SequenceSpec, calibrate, eval_overrides, render_sequences
    from poevp_optics.camera.camera import Camera
    from poevp_optics.scene.load import load_scene

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    spec = load_scene(SCENES / "highbeam_plate", eval_overrides((46, 80), 2, 2, "KA 7391"))
    cam = Camera.from_params(spec.resolved.camera)
    cal = calibrate(spec, cam.guard_px)
    seqs = [SequenceSpec("KA 7391", "lateral", 4.0, 2)]
    logs = []
    ex0 = render_sequences(spec, seqs, cal, cam.guard_px, log=logs.append)
    (path,) = (tmp_path / "eval").glob("*.npz")
    clean = path.read_bytes()

    def other_size(p):
        with np.load(p) as z:
            np.savez(p, mean=z["mean"][:, :, 1:], var=z["var"][:, :, 1:], roi=z["roi"])

    for k, damage in enumerate([_truncate, _resigned(other_size)]):
        damage(path)
        ex = render_sequences(spec, seqs, cal, cam.guard_px, log=logs.append)
        _assert_healed(capsys, path, clean, logs, k + 2)
        for a, b in zip(ex0[0], ex[0]):
            assert len(a.subframes) == len(b.subframes) == 2 and a.roi == b.roi
            for sa, sb in zip(a.subframes, b.subframes):
                np.testing.assert_array_equal(sa, sb)
            np.testing.assert_array_equal(a.variance, b.variance)
    render_sequences(spec, seqs, cal, cam.guard_px, log=logs.append)
    assert len(logs) == 3


# ----------------------------------------------------------------------------- end to end: a night_road render
# night_road at 1/24 of its 1920x1080 mirrors (the focal length and the mask's sizes scaled with it,
# as tests/unit/test_resolve.py runs it); 3 frames: its two white initialisation frames and one loop frame.
RENDER = ["render", str(SCENES / "night_road"), "--quiet", "--set", "render.resolution=[45,80]",
          "--set", "timing.frames=3", "--set", "objective.focal_length_m=0.002878", "--set", "mask.smooth_px=1.0",
          "--set", "attenuator.serve_min_mirrors=6"]
#: Run outputs that carry wall-clock times or the output folder's own record.
TIMED = {"report.json", "report.html", ".poevp-output.json"}


def _render(cache: Path, out: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "POEVP_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-m", "poevp_optics.cli", *RENDER, "--out", str(out)], cwd=ROOT,
                          env=env, capture_output=True, text=True, timeout=600)


def _outputs(out: Path) -> dict[str, bytes]:
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.name not in TIMED}


def _report(out: Path) -> dict:
    def strip(o):
        if isinstance(o, dict):
            return {k: strip(v) for k, v in o.items() if not k.endswith("seconds")}
        return [strip(v) for v in o] if isinstance(o, list) else o

    return strip(json.loads((out / "report.json").read_text()))


@pytest.fixture(scope="module")
def clean_run(tmp_path_factory):
    """A clean cache filled by one render, and that render's outputs."""
    root = tmp_path_factory.mktemp("heal")
    r = _render(root / "cache", root / "out")
    assert r.returncode == 0, r.stderr
    assert "failed its check" not in r.stderr
    return root / "cache", _outputs(root / "out"), _report(root / "out")


def _other_npz(path: Path) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, a=np.zeros(3), image_shape=np.array([0, 0]))


E2E = {          # the cache files a night_road render reads (its one PSF grid: the rendered field), each kind damaged
    "psf_grid_other_arrays": ("objective/psf-*.npz", [_resigned(_other_npz)]),
    "ri_table_random_bytes": ("objective/ri-*.npz", [_random_bytes]),
    "mesh_of_another_car": ("meshes/vehicle_*.ply", [_resigned(_other_mesh)]),   # the scene's vehicles' parts
    "plate_of_another_size": ("plates/plate_*.png", [_resigned(lambda p: write_png(p, np.full((22, 104), 255, np.uint8)))]),
}


@pytest.mark.slow
def test_a_render_on_a_damaged_cache_heals_it_and_writes_the_same_bytes(clean_run, tmp_path):
    """`poevp render` on a copy of the clean cache with every kind's files damaged at once (each
    kind its own way, E2E): exit 0, one note per damaged file, each rebuilt to the clean bytes,
    and every output image and report value (wall-clock times aside) byte for byte the clean
    run's. One run heals them all: each kind's check and rebuild is independent of the others'."""
    cache0, outputs0, report0 = clean_run
    cache = tmp_path / "cache"
    shutil.copytree(cache0, cache)
    damaged = []
    for case, (pattern, damages) in E2E.items():
        files = sorted(cache.glob(pattern))
        assert len(files) >= len(damages), (case, pattern)
        for k, p in enumerate(files):
            damages[k % len(damages)](p)
        damaged += files
    r = _render(cache, tmp_path / "out")
    assert r.returncode == 0, r.stderr
    for p in damaged:
        assert len(_note_lines(r.stderr, p)) == 1, (p, r.stderr)
        assert p.read_bytes() == (cache0 / p.relative_to(cache)).read_bytes() and cc.checksum_problem(p) is None, p
    assert r.stderr.count("failed its check") == len(damaged), r.stderr
    out = _outputs(tmp_path / "out")
    assert out.keys() == outputs0.keys()
    assert [k for k in out if out[k] != outputs0[k]] == []
    assert _report(tmp_path / "out") == report0
