"""report.html (apps/run/report_html.py, issue 29): written by every render run, self-contained,
frames and plate zoom as the run's own pixels, and it opens in headless Chromium with its
player running and no console message."""

from __future__ import annotations

import base64
import json
import re
import shutil
import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest

from poevp_optics.apps.run.report_html import MARKER, MAX_FRAMES, MAX_PANEL_W, render_html, shown_frames
from poevp_optics.cli import main
from tests.conftest import SCENES

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _images(page: str) -> list[np.ndarray]:
    """Every data-URI PNG in the page (attributes and the player's JSON), decoded."""
    out = []
    for b64 in re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page):
        out.append(cv2.imdecode(np.frombuffer(base64.b64decode(b64), np.uint8), cv2.IMREAD_UNCHANGED))
    return out


def _chromium(url: str, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([CHROMIUM, *FLAGS, f"--user-data-dir={tmp_path / 'chromium-profile'}",
                           "--enable-logging=stderr", "--v=0", *extra, url],
                          capture_output=True, text=True, timeout=120)


def _console(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if ":CONSOLE" in line or "Uncaught" in line]


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report_html") / "run"
    assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "3",
                 "--spp", "4", "--resolution", "48x64", "--set", 'plate.text="AB 1234"']) == 0
    return out


def test_every_render_run_writes_a_self_contained_report_html(smoke_run):
    page = (smoke_run / "report.html").read_text()
    assert (smoke_run / "report.json").is_file()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:)?//""", page)     # nothing fetched from a network
    data = json.loads(re.search(r'<script type="application/json" id="frames-data">(.*?)</script>',
                                page, re.S).group(1).replace("<\\/", "</"))
    assert data["labels"] == ["scene (tone-mapped)", "LDR twin", "mask", "encoded capture",
                              "reconstruction (tone-mapped)"]
    assert [f["index"] for f in data["frames"]] == [0, 1, 2] and data["frames"][0]["text"] == "AB 1234"
    # the encoded capture panel of frame 2 is the run's own capture PNG, pixel for pixel
    uri = data["frames"][2]["panels"][3]
    panel = cv2.imdecode(np.frombuffer(base64.b64decode(uri.split(",", 1)[1]), np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(panel, cv2.imread(str(smoke_run / "capture" / "frame_0002.png"), cv2.IMREAD_UNCHANGED))
    # the plate zoom: the ROI box and a quarter of its size around it, scaled by an integer factor
    rec = json.loads((smoke_run / "report.json").read_text())["per_frame"][2]
    y0, x0, y1, x1 = rec["roi"]
    my, mx = max(2, (y1 - y0) // 4), max(2, (x1 - x0) // 4)
    crop = panel[max(0, y0 - my):y1 + my, max(0, x0 - mx):x1 + mx]
    zoom = cv2.imdecode(np.frombuffer(base64.b64decode(data["frames"][2]["plate"][0].split(",", 1)[1]),
                                      np.uint8), cv2.IMREAD_UNCHANGED)
    k = zoom.shape[1] // crop.shape[1]
    assert k >= 2 and np.array_equal(zoom, np.repeat(np.repeat(crop, k, 0), k, 1))


def test_panels_are_downscaled_and_long_runs_strided(tmp_path):
    n, h, w = 100, 360, 1280
    (tmp_path / "capture").mkdir()
    for i in range(n):
        cv2.imwrite(str(tmp_path / "capture" / f"frame_{i:04d}.png"), np.full((h, w), i, np.uint8))
    report = {"scene": "big", "sensor": {"bits": 8}, "per_frame": [{"index": i} for i in range(n)]}
    page = render_html(tmp_path, report)
    imgs = _images(page)
    assert imgs and max(im.shape[1] for im in imgs) <= MAX_PANEL_W
    shown = shown_frames(n)
    assert len(shown) == MAX_FRAMES and shown[0] == 0 and shown[-1] == n - 1
    # frame i's panel is flat at level i (INTER_AREA of a constant image keeps it)
    levels = sorted({int(im[0, 0]) for im in imgs})
    assert levels == shown


@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (scripts/setup.sh installs it as root)")
def test_report_opens_in_headless_chromium_without_console_errors(smoke_run, tmp_path):
    # the check catches a page error: a control page that throws is reported
    bad = tmp_path / "bad.html"
    bad.write_text("<!DOCTYPE html><html><body><script>throw new Error('control');</script></body></html>")
    assert any("control" in line for line in _console(_chromium(bad.as_uri(), tmp_path, "--dump-dom").stderr))

    url = (smoke_run / "report.html").as_uri()
    dom = _chromium(url, tmp_path, "--dump-dom")
    assert _console(dom.stderr) == [], _console(dom.stderr)
    assert re.search(rf'<div id="js-status">{MARKER} 3 frames</div>', dom.stdout)   # the player's script ran
    assert 'id="frame-label">frame 0 (1 of 3 shown, 3 in the run)' in dom.stdout
    shot = tmp_path / "shot.png"
    run = _chromium(url, tmp_path, f"--screenshot={shot}", "--window-size=1400,1000", "--hide-scrollbars")
    assert _console(run.stderr) == [], _console(run.stderr)
    img = cv2.imread(str(shot), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape == (1000, 1400)
    # non-blank: not one flat colour, and the frames' grey pixels cover a tenth of the view (text alone: ~2 %)
    assert img.std() > 20 and ((img > 40) & (img < 200)).mean() > 0.1
