"""The paper's simulation protocol (Sec. 6) as one `poevp evaluate` configuration (issue 20): an
ldr_highlight scene runs Eq. 3 at E = 9, 29, 49 with Eq. 2's (Vs, a, b) = (200, 0.9, 0), and the
report puts it beside the paper's Table 2."""

from __future__ import annotations

import dataclasses
import json

import pytest

pytest.importorskip("rapidocr_onnxruntime")

from poevp_optics.apps.evaluate.eval_paper import PAPER_E, paper_overrides  # noqa: E402
from poevp_optics.apps.evaluate.evaluate import check_config, evaluate, quick_config  # noqa: E402
from poevp_optics.core.exceptions import UserError  # noqa: E402
from poevp_optics.core.paths import SCENES_DIR  # noqa: E402
from poevp_optics.scene.load import load_scene  # noqa: E402

SCENE = SCENES_DIR / "ldr_highlight_demo"


def test_paper_overrides_set_the_papers_coefficients():
    spec = load_scene(SCENE, paper_overrides(49.0))
    assert (spec.source.e, spec.source.r_px) == (49.0, 50.0)
    # Eq. 2's linear reading by default: the one that reproduces the paper in the paper's camera
    assert (spec.mask.law, spec.mask.vs, spec.mask.a, spec.mask.b) == ("threshold_linear", 200.0, 0.9, 0.0)
    assert spec.source.e_domain == "display"                  # Eq. 3 on the 8-bit values (Sec. 4.A)
    with pytest.raises(UserError, match="paper-law"):
        check_config(dataclasses.replace(quick_config(SCENE), paper_law="white"))


def test_paper_protocol_runs_and_ldr_reads_no_more_than_the_oracle(tmp_path):
    cfg = quick_config(SCENE)
    rep = evaluate(tmp_path, cfg, log=lambda *a: None)
    assert rep["protocol"] == "paper"
    n_frames = load_scene(SCENE).timing.frames - 2          # the loop's two white frames are not scored
    for e in PAPER_E:
        cells = {m: rep["cells"][f"paper|0|{e:g}|{m}"] for m in cfg.methods}
        for c in cells.values():
            assert c["frames"] == n_frames and c["alpr"]["ci95"][0] <= c["alpr"]["pct"] <= c["alpr"]["ci95"][1]
        ldr, oracle = cells["ldr"], cells["oracle"]
        # same sensor noise for both (common seeds): the mask can only take light away from
        # clipped pixels, so the oracle's plate never holds less information than the LDR's
        assert ldr["alpr"]["read"] <= oracle["alpr"]["read"], e
        assert ldr["entropy_bits"] < oracle["entropy_bits"], e
    md = (tmp_path / "evaluation.md").read_text()
    # the physical camera's default law is the project's exposure controller, labelled ours
    assert rep["config"]["paper_law"] == "exposure_controller"
    assert "94.86" in md and "65.07" in md and "physically rendered" in md and "`exposure_controller` (ours" in md
    assert "JN F9H28" in md                                   # the text comes from the source's CSV
    r = json.loads((tmp_path / "report.json").read_text())
    assert set(r["findings"]["paper_protocol"]) == {"9", "29", "49"}
    assert all(v["ldr_le_oracle"] for v in r["findings"]["paper_protocol"].values())
