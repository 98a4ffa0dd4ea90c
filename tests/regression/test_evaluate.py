"""Recognition comparison (issue 8), quick set: POE-VP reads highlighted plates LDR cannot."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("rapidocr_onnxruntime")

from poevp_optics.apps.evaluate import E_LEVELS, METHODS, evaluate  # noqa: E402
from poevp_optics.analysis.recognition import correct, normalise  # noqa: E402


def test_normalisation_and_exact_match():
    assert normalise("ka 7391.") == "KA7391"
    assert correct("KA 7391", "KA7391") and not correct("KA 739", "KA 7391") and not correct("", "")


def test_quick_evaluation_reproduces_the_papers_ordering(tmp_path):
    s = evaluate(tmp_path, quick=True, progress=False, log=lambda *a: None)
    strong = str(max(E_LEVELS))
    ldr, dmvfn = s["ldr"][strong], s["dmvfn"][strong]
    # the LDR plate is clipped at E = 49; POE-VP with the shipped predictor reads it
    assert dmvfn["accuracy_pct"] >= 80.0
    assert ldr["accuracy_pct"] <= 20.0 or dmvfn["accuracy_pct"] >= 5 * ldr["accuracy_pct"]
    assert dmvfn["entropy_bits"] > 3.0 * max(ldr["entropy_bits"], 1e-9) or ldr["entropy_bits"] == 0
    for m in METHODS:
        assert s[m]["all"]["frames"] > 0
    md = (tmp_path / "evaluation.md").read_text()
    assert "65.07" in md and "94.86" in md and "out of scope" in md
    r = json.loads((tmp_path / "report.json").read_text())
    assert "fusion" in r["explanation"]
    assert (tmp_path / "examples.png").is_file() and (tmp_path / "frames.csv").is_file()
