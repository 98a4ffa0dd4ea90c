"""`poevp sweep`/`search`'s stored-render key follows the plate font and the render code: a
stored render must not outlive an edit to the font file or to render/, sources/, core/."""

from __future__ import annotations

from poevp_optics.render import render_cache
from poevp_optics.scene.load import load_scene
from poevp_optics.sources import plates
from tests.conftest import SCENES

TINY = ["render.resolution=[24,32]", "timing.frames=2", "render.spp=4"]


def test_font_and_code_move_the_sweep_render_key(monkeypatch):
    spec = load_scene(SCENES / "smoke", TINY, cross_checks=False)

    def _group():
        return render_cache.render_group(spec.resolved.render, {"xml": "f" * 64})

    base = _group()
    assert _group() == base                                                   # deterministic
    monkeypatch.setattr(plates, "plate_font_sha256", lambda: "0" * 64)        # another font file
    assert _group() != base
    monkeypatch.undo()
    assert _group() == base
    monkeypatch.setattr(render_cache, "code_digest", lambda *a, **k: "edited")  # edited render code
    assert _group() != base


def test_evaluate_keys_its_sequences_with_the_same_font_and_code():
    from poevp_optics.apps.evaluate import eval_sequences as es

    spec = load_scene(SCENES / "smoke", TINY, cross_checks=False)
    got = es.render_fingerprint(spec, 5)
    want = render_cache.render_code_inputs()
    assert {k: got[k] for k in want} == want
    assert want["code"] == render_cache.code_digest(render_cache.RENDER_CODE, render_cache.PACKAGE_DIR)
