"""The cache keys of `poevp evaluate`'s rendered sequences and of the recognition page's road
renders cover every input a render's content depends on: a change to any of them (a scene or
render setting, the plate font, the render code, the backend, the guard band) gives another
key, and a change to a setting the render never reads (the DMD's contrast) keeps it."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from poevp_optics.apps.evaluate import eval_sequences as es
from poevp_optics.render import render_cache as rc
from poevp_optics.core.paths import SCENES_DIR
from poevp_optics.scene.load import load_scene

TEXT = "BIO 1080"
SEQ = es.SequenceSpec(TEXT, "lateral", 8.0, 4, 1)


def _spec(*extra: str):
    return load_scene(SCENES_DIR / "highbeam_plate", [*es.eval_overrides((46, 80), 2, 4, TEXT), *extra])


def _key(spec, guard_px: int = 5, seq: es.SequenceSpec = SEQ) -> str:
    times = es.node_times(spec, seq.frames)
    offs = np.zeros((times.size, 3))
    offs[:, 0] = np.linspace(-0.2, 0.2, times.size)
    return es.content_key(spec, seq, times, offs, guard_px)


@pytest.fixture(scope="module")
def base():
    spec = _spec()
    return spec, _key(spec)


def test_key_is_reproducible_and_ignores_camera_only_settings(base):
    spec, key = base
    assert _key(_spec()) == key
    assert _key(_spec("dmd.contrast_ratio=500.0")) == key          # the camera's, not the render's


@pytest.mark.parametrize("override", ["render.seed=2", "render.spp=3", "render.resolution=[48,80]",
                                      "plate.format='us'", "spectra.highbeam.intensity_cd=60000.0",
                                      "render.variant='scalar_spectral'"])
def test_every_render_setting_moves_the_key(base, override):
    assert _key(_spec(override)) != base[1]


def test_sequence_guard_font_code_and_backend_move_the_key(base, monkeypatch):
    spec, key = base
    assert _key(spec, seq=es.SequenceSpec(TEXT, "lateral", 8.0, 4, -1)) != key   # other poses
    assert _key(spec, guard_px=6) != key
    from poevp_optics.sources import plates

    monkeypatch.setattr(plates, "plate_font_sha256", lambda: "0" * 64)          # another font file
    assert _key(spec) != key
    monkeypatch.undo()
    monkeypatch.setattr(rc, "code_digest", lambda *a, **k: "edited")            # edited render code
    assert _key(spec) != key
    monkeypatch.undo()
    monkeypatch.setattr(es, "render_backend", lambda requested: "cuda-elsewhere")
    assert _key(spec) != key


def test_code_digest_follows_every_source_file(tmp_path):
    root = tmp_path / "pkg"
    for rel in ("render/a.py", "render/sub/b.py", "sources/c.py", "core/d.py"):
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(f"X = {rel!r}\n")
    (root / "render" / "notes.txt").write_text("not code")
    first = rc.code_digest(rc.RENDER_CODE, root)
    (root / "render" / "notes.txt").write_text("still not code")
    (root / "core" / "d.py").write_text('"""A docstring."""\n\nX = (  # a comment\n    "core/d.py")\n')
    assert rc.code_digest.__wrapped__(rc.RENDER_CODE, root) == first          # same code, other layout
    (root / "render" / "sub" / "b.py").write_text("X = 2\n")
    edited = rc.code_digest.__wrapped__(rc.RENDER_CODE, root)
    assert edited != first
    (root / "sources" / "new.py").write_text("")
    assert rc.code_digest.__wrapped__(rc.RENDER_CODE, root) not in (first, edited)
    shutil.rmtree(root / "core")
    assert rc.code_digest.__wrapped__(("render", "sources"), root) == rc.code_digest.__wrapped__(rc.RENDER_CODE, root)
    assert rc.code_digest.__wrapped__(("render/a.py",), root) != rc.code_digest.__wrapped__(("render",), root)


def test_road_render_key_covers_frames_and_font(monkeypatch):
    from benchmarks.recognition import render_key

    spec = _spec()
    key = render_key(spec, 5)
    assert render_key(_spec("timing.frames=5"), 5) != key
    from poevp_optics.sources import plates

    monkeypatch.setattr(plates, "plate_font_sha256", lambda: "1" * 64)
    assert render_key(spec, 5) != key
