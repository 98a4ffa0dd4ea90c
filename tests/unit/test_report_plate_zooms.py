"""report.html with every plate in view (`render.roi_shape = "plates"`): each plate record of a
shown frame gets its own zoom, cut from that frame's encoded capture, and its own numbers
(white of the encoded capture and LDR twin, band, MC error, distance, height); a plate out of
view says so and gets no zoom. The run folder is written here (two plates drawn at known boxes
in a 3-frame capture), so the page is checked against pixels and numbers set by the test."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess

import cv2
import numpy as np
import pytest

from poevp_optics.apps.run.report_html import MARKER, write_report_html

BOXES = {"near": [20, 10, 30, 50], "far": [8, 60, 12, 76]}          # (y0, x0, y1, x1), sensor pixels


def _plate(ident, box, white_enc, white_ldr, rel, dist, band=(0.4, 0.9)):
    if box is None:
        return {"id": ident, "text": f"{ident.upper()} 1", "in_view": False, "distance_m": dist,
                "visible_fraction": 0.0, "box": None, "height_px": None, "rel_error": None, "white": None,
                "in_band": None}
    return {"id": ident, "text": f"{ident.upper()} 1", "in_view": True, "distance_m": dist, "visible_fraction": 1.0,
            "box": box, "height_px": box[2] - box[0], "rel_error": rel,
            "white": {"ldr": white_ldr, "encoded": white_enc}, "in_band": band[0] <= white_enc <= band[1]}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("plates_report")
    (out / "capture").mkdir()
    rng = np.random.default_rng(5)
    per_frame = []
    for i in range(3):
        img = rng.integers(0, 60, (40, 96), dtype=np.uint8)
        for k, (y0, x0, y1, x1) in enumerate(BOXES.values()):
            img[y0:y1, x0:x1] = 120 + 40 * k + 10 * i          # each plate its own grey per frame
        cv2.imwrite(str(out / "capture" / f"frame_{i:04d}.png"), img)
        plates = [_plate("near", BOXES["near"], 0.31 + 0.1 * i, 1.0, 0.0213 + 0.001 * i, 22.4 - i),
                  _plate("far", BOXES["far"], 0.62, 0.71, 0.0287, 46.0 + i),
                  _plate("hidden", None, None, None, None, 29.2)]
        per_frame.append({"index": i, "init": i == 0, "roi": BOXES["near"], "plates": plates})
    report = {"scene": "two_plates", "frames": 3, "per_frame": per_frame,
              "metrics": {"plates": {"band": [0.4, 0.9], "per_plate": {}, "definition": "-"}}}
    write_report_html(out, report)
    return out, report


def _data(page: str) -> dict:
    return json.loads(re.search(r'<script type="application/json" id="frames-data">(.*?)</script>',
                                page, re.S).group(1).replace("<\\/", "</"))


def _decode(uri: str) -> np.ndarray:
    return cv2.imdecode(np.frombuffer(base64.b64decode(uri.split(",", 1)[1]), np.uint8), cv2.IMREAD_UNCHANGED)


def test_every_plate_record_gets_its_zoom_and_numbers(run_dir):
    out, report = run_dir
    page = (out / "report.html").read_text()
    assert 'id="plate-zooms"' in page and "Plate (zoomed" not in page     # every plate, not the nearest only
    data = _data(page)
    assert len(data["frames"]) == 3
    for f, rec in zip(data["frames"], report["per_frame"]):
        capture = cv2.imread(str(out / "capture" / f"frame_{rec['index']:04d}.png"), cv2.IMREAD_UNCHANGED)
        assert [p["id"] for p in f["plates"]] == ["near", "far", "hidden"]
        for shown, p in zip(f["plates"], rec["plates"]):
            if not p["in_view"]:
                assert shown["zoom"] == "" and shown["numbers"] == "hidden (HIDDEN 1): out of view"
                continue
            # the zoom: the box and a quarter of its size around it, nearest neighbour x an integer
            y0, x0, y1, x1 = p["box"]
            my, mx = max(2, (y1 - y0) // 4), max(2, (x1 - x0) // 4)
            crop = capture[max(0, y0 - my):y1 + my, max(0, x0 - mx):x1 + mx]
            zoom = _decode(shown["zoom"])
            k = zoom.shape[1] // crop.shape[1]
            assert k >= 2 and np.array_equal(zoom, np.repeat(np.repeat(crop, k, 0), k, 1))
            # the numbers: this record's, not the nearest plate's
            w = p["white"]
            assert f"white {w['encoded']:.2f} of full scale, LDR twin {w['ldr']:.2f}" in shown["numbers"]
            assert ("(in band 0.4-0.9)" if p["in_band"] else "(out of band 0.4-0.9)") in shown["numbers"]
            assert f"MC error {p['rel_error'] * 100:.2f} %" in shown["numbers"]
            assert f"{p['distance_m']:.1f} m; {p['height_px']} px tall" in shown["numbers"]
    # frame 1's near plate at white 0.41 is in band, frame 0's at 0.31 is not
    assert "(out of band" in data["frames"][0]["plates"][0]["numbers"]
    assert "(in band" in data["frames"][1]["plates"][0]["numbers"]


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/setup.sh installs it as root)")
def test_the_player_shows_every_plate_of_the_frame(run_dir, tmp_path):
    out, report = run_dir
    dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                          "--disable-background-networking", "--disable-component-update", "--disable-sync",
                          f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0",
                          "--dump-dom", (out / "report.html").as_uri() + "#frame=2"],
                         capture_output=True, text=True, timeout=120)
    assert not [ln for ln in dom.stderr.splitlines() if ":CONSOLE" in ln or "Uncaught" in ln]
    assert MARKER in dom.stdout
    zooms = re.search(r'<div id="plate-zooms"[^>]*>(.*?)</div>', dom.stdout, re.S).group(1)
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", zooms)
    assert len(captions) == 3 and captions[2] == "hidden (HIDDEN 1): out of view"
    assert "white 0.51 of full scale" in captions[0] and "white 0.62 of full scale" in captions[1]
    assert len(re.findall(r'<img alt="plate (near|far)" src="data:image/png', zooms)) == 2
