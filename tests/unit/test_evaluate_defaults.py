"""`poevp evaluate`'s defaults on the paper's protocol (a law per camera) and the line that says
why a run reads nothing."""

from __future__ import annotations

import dataclasses

import pytest

from poevp_optics.apps.evaluate.eval_paper import DEFAULT_LAWS, PAPER_LAW, protocol_law
from poevp_optics.apps.evaluate.eval_report import CLIPPED_SHARE, DARK_P90, zero_read_reason
from poevp_optics.apps.evaluate.evaluate import EvalConfig, check_config, quick_config
from poevp_optics.core.paths import SCENES_DIR

SCENE = SCENES_DIR / "ldr_highlight_demo"


def test_protocol_law_defaults_per_camera_and_a_given_law_wins():
    cfg = EvalConfig(scene=SCENE)
    assert cfg.paper_law == ""
    check_config(quick_config(SCENE))                                   # "" is accepted
    assert PAPER_LAW == "threshold_linear"
    assert protocol_law(dataclasses.replace(cfg, camera="paper")) == "threshold_linear"
    assert protocol_law(dataclasses.replace(cfg, camera="physical")) == "exposure_controller"
    assert protocol_law(dataclasses.replace(cfg, camera="paper", paper_law="threshold_ratio")) == "threshold_ratio"
    assert set(DEFAULT_LAWS) == {"paper", "physical"}


def _row(method, ok=False, rec_ok=False, clipped=0.0, p90=200.0, frame=2, alpr_text="", rec_text=""):
    return {"method": method, "frame": frame, "text": "JN F9H28", "alpr_ok": ok, "rec_ok": rec_ok,
            "plate_clipped": clipped, "plate_p90": p90, "alpr_text": alpr_text, "rec_text": rec_text}


def test_no_reason_when_a_poevp_method_reads():
    assert zero_read_reason([_row("ldr"), _row("oracle", ok=True)]) is None
    assert zero_read_reason([]) is None


def test_clipped_plate_names_the_law_that_cannot_unclip():
    rows = [_row(m, clipped=c) for m, c in (("ldr", 1.0), ("oracle", CLIPPED_SHARE), ("hold", 0.9))]
    why = zero_read_reason(rows, "threshold_ratio")
    assert why.startswith("Every method reads 0 % (3 reads of ldr, oracle, hold)")
    assert "clipped" in why and "ldr 100 %, oracle 25 %, hold 90 %" in why
    assert "threshold_linear" in why                                   # the reading that reproduces the paper
    assert "threshold_linear" not in zero_read_reason(rows, "exposure_controller")


def test_dark_plate_detector_miss_and_other_text():
    dark = [_row(m, p90=DARK_P90 - 1, clipped=0.0) for m in ("ldr", "oracle")]
    assert "dark in every method" in zero_read_reason(dark)
    found = [_row("oracle", rec_ok=True), _row("oracle", frame=3), _row("hold")]
    assert "reads 1 of 3 frames" in zero_read_reason(found) and "detector" in zero_read_reason(found)
    other = [_row("oracle", alpr_text="F9H28", rec_text="NF9H28"), _row("hold", clipped=0.9)]
    why = zero_read_reason(other)
    assert "'F9H28' (ALPR) / 'NF9H28' (plate box) for 'JN F9H28'" in why
    # each method's state named: the clipped one apart from the one that reads other text
    assert "clipped in hold (90 % of its box at 255)" in why and "in oracle it is neither clipped nor dark" in why
    assert "clipped in oracle" not in why
    # one method clipped, the other dark, none neither: both named, no OCR example to give
    mixed = zero_read_reason([_row("oracle", clipped=0.9), _row("hold", p90=DARK_P90 - 1)])
    assert "clipped in oracle (90 % of its box at 255)" in mixed and "dark in hold (90th percentile 63" in mixed
    assert "OCR reads" not in mixed


def test_baselines_reading_while_every_poevp_method_reads_nothing():
    rows = [_row("fusion_deghost", ok=True), _row("oracle", clipped=1.0), _row("hold", clipped=1.0)]
    why = zero_read_reason(rows, "threshold_exp")
    assert why.startswith("Every POE-VP method reads 0 % (2 reads of oracle, hold)")


@pytest.mark.slow
def test_a_run_that_reads_nothing_says_why_first(tmp_path, capsys):
    """The paper's camera with Eq. 2's ratio reading: the oracle stays clipped (the reading dims a
    prediction clipped at 255 by at most a Vs / 255 = 0.71), so nothing reads; the report's first
    line after the title and the command's first summary line say so."""
    from poevp_optics.cli import main

    out = tmp_path / "ev"
    rc = main(["evaluate", str(SCENE), "--quick", "--camera", "paper", "--paper-law", "threshold_ratio",
               "--predictors", "oracle", "--baselines", "ldr", "--out", str(out), "--quiet"])
    assert rc == 0
    lines = (out / "evaluation.md").read_text().splitlines()
    assert lines[2].startswith("**Every method reads 0 %") and "threshold_linear" in lines[2]
    printed = capsys.readouterr().out.splitlines()
    assert printed[0].startswith("poevp: Every method reads 0 %")
