"""benchmarks/recognition.py without OCR or rendering: the page from a small hand-made table of
reads, the Wilson cells it prints, the ALPR-miss causes and the confusion count, and the fusion
variants on a tiny synthetic sequence."""

from __future__ import annotations

import math

import numpy as np

from benchmarks import recognition as rec


def _row(scene, condition, method, frame, alpr, rec_ok, alpr_text="", rec_text="", text="BIO 1080", **kw):
    return {"scene": scene, "camera": "physical camera", "condition": condition, "factor": "", "method": method,
            "frame": frame, "text": text, "alpr_ok": alpr, "rec_ok": rec_ok, "alpr_text": alpr_text,
            "rec_text": rec_text, "detections": kw.get("detections", 1), "plate_clipped": 0.0, "plate_p90": 200.0}


def _wilson_closed_form(k, n, z=1.959963984540054):
    """Wilson (1927): (k + z^2/2)/(n + z^2) -+ z sqrt(k(n-k)/n + z^2/4)/(n + z^2), written out here."""
    c = (k + z * z / 2) / (n + z * z)
    h = z * math.sqrt(k * (n - k) / n + z * z / 4) / (n + z * z)
    return max(0.0, c - h), min(1.0, c + h)


def test_wilson_cell_prints_the_score_interval():
    for k, n in ((0, 6), (3, 4), (18, 18), (7, 19)):
        lo, hi = _wilson_closed_form(k, n)
        assert rec.wilson_cell(k, n) == f"{k}/{n} = {100 * k / n:.0f} % [{100 * lo:.0f}-{100 * hi:.0f}]"
    assert rec.wilson_cell(0, 0) == "-"
    # 4/6: centre (4 + 1.92)/(6 + 3.84) = 0.602, half 0.302 -> [30-90] (hand arithmetic)
    assert rec.wilson_cell(4, 6) == "4/6 = 67 % [30-90]"


def test_miss_causes_from_the_whole_frame_text():
    r = _row("s", "c", "flow", 0, False, True)
    assert rec.miss_cause({**r, "alpr_text": "", "detections": 0}) == "no text detected over the plate"
    assert "elsewhere" in rec.miss_cause({**r, "alpr_text": "", "detections": 3})
    assert "part of the plate" in rec.miss_cause({**r, "alpr_text": "BIO10"})
    assert "beside the plate" in rec.miss_cause({**r, "alpr_text": "XBIO1080"})
    assert "misread" in rec.miss_cause({**r, "alpr_text": "8IO1O80"})


def test_confusions_count_each_swapped_character():
    rows = [_row("s", "c", "ldr", 0, False, False, alpr_text="8IO 1O80", rec_text="BI0 1080"),
            _row("s", "c", "ldr", 1, False, False, alpr_text="BIO", rec_text="")]       # not same length: ignored
    c = rec.confusions(rows)
    # ALPR: B->8 and the digit 0 (second of "1080") -> O; box: the letter O -> 0
    assert c == {("B", "8"): 1, ("0", "O"): 1, ("O", "0"): 1}


def test_page_from_a_small_table():
    rows = []
    for t in range(4):   # flow: the box reads 4/4, whole-frame ALPR 1/4 -> a 75-point gap
        rows.append(_row("highbeam_plate", "E = 9, 24 px/frame", "flow", t, t == 0, True,
                         alpr_text="BIO 1080" if t == 0 else "BIO10", rec_text="BIO 1080"))
        rows.append(_row("highbeam_plate", "E = 9, 24 px/frame", "ldr", t, False, False))
    for e in (9, 29):
        for t in range(2, 5):
            rows.append({**_row("ldr_highlight_demo", f"E = {e}", "fusion_classic", t, e == 9, e == 9, text="JN F9H28"),
                         "camera": "paper camera"})
    img = np.zeros((20, 40), np.uint8)
    examples = {("highbeam_plate", "physical camera", "E = 9, 24 px/frame", "flow"): (img, (5, 5, 10, 30), rows[2])}
    text = rec.page({"rows": rows, "examples": examples, "date": "2026-01-01", "label": "quick", "command": "cmd",
                     "seconds": 60.0, "machine": "m", "road_scale": "1/3", "gaps_png": True, "protocol": "P"})
    assert "**These are the quick settings" in text
    assert "| E = 9, 24 px/frame | flow | 1/4 = 25 % [5-70] | 4/4 = 100 % [51-100] |  |" in text
    # the demo's pooled fusion row carries the paper's number; 3 of 6 frames read
    assert "| **pooled** | fusion_classic | 3/6 = 50 % [19-81] | 3/6 = 50 % [19-81] | 65.07 % |" in text
    gap = text.split("## Full ALPR against recognition only")[1].split("##")[0]
    assert "3 x the detector's box covers part of the plate" in gap and "panel 1: frame 1" in gap
    assert "recognition_gaps.png" in gap
    assert "ldr" not in gap                   # only POE-VP rows are examined


def test_fusion_variants_on_a_synthetic_sequence():
    from poevp_optics.apps.evaluate.paper_camera import PaperSequence

    # a bright flat field at 4x the clip: at coefficient 1/8 it is 128 code values, at 1/5 204, at 1 clipped
    hdr = [np.full((32, 48), 1020.0) for _ in range(3)]
    seq = PaperSequence(hdr, {}, {}, 9.0)
    after = rec.fused(seq, 2, False, rec.FusionVariant("x", after_clip=True))
    # after the cut-off every exposure is flat: 255/8, 255/5, 255 -> a flat fusion between them
    assert np.ptp(after) == 0 and 255 / 8 - 1 <= after[0, 0] <= 255
    one = rec.fused(seq, 2, False, rec.VARIANTS[1])
    # one channel, flat frames (zero contrast): equal weights, the mean of 128, 204, 255 = 195.7
    np.testing.assert_allclose(one, np.mean([128, 204, 255]), atol=1.0)


def test_zero_read_section_names_the_clipped_plate():
    rows = [{**_row("night_road", "beams x10", m, t, False, False), "plate_clipped": 0.9}
            for m in ("ldr", "flow") for t in range(3)]
    lines = rec.zero_read_section(rows)
    assert lines[0] == "## Where no POE-VP frame reads"
    assert "night_road / physical camera / beams x10" in lines[2] and "stays clipped" in lines[2]
    rows[3] = {**rows[3], "alpr_ok": True}            # a flow frame reads: nothing to explain
    assert rec.zero_read_section(rows) == []
