"""What users read speaks of the camera and their problem, not of the project's history: no
issue numbers and no commit hashes in the shipped scenes, the documentation (README, docs/, the
results pages the site shows), every command's --help, and a rendered report.html / report.json.
History lives in git.

Commit hashes are found by what they are: every hexadecimal token of 7-40 characters in those
texts is looked up among this repository's commits (`git rev-list --all`), so a SHA-256 of a
weights file or a colour code is not mistaken for one."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT, SCENES

ISSUE = re.compile(r"\bissues?\s*#?\s*\d+(?:\s*(?:,|and|-)\s*\d+)*|\(#\d+\)|\bin git history\b", re.I)
HEX = re.compile(r"(?<![0-9A-Za-z_])[0-9a-f]{7,40}(?![0-9A-Za-z_])")

#: Commands whose --help a user reads.
COMMANDS = ["render", "validate", "compare", "chart", "sweep", "evaluate", "train-data",
            "train-predictor", "schema", "info"]


def _commits() -> list[str] | None:
    try:
        out = subprocess.run(["git", "rev-list", "--all"], cwd=ROOT, capture_output=True, text=True,
                             timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.split() if out.returncode == 0 and out.stdout.strip() else None


COMMITS = _commits()


def _findings(text: str) -> list[str]:
    found = [m.group(0) for m in ISSUE.finditer(text)]
    if COMMITS:
        for m in HEX.finditer(text):
            tok = m.group(0)
            if any(c.isalpha() for c in tok) and any(c.startswith(tok) for c in COMMITS):
                found.append(f"commit {tok}")
    return found


def _user_files() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")),
             *sorted((ROOT / "benchmarks" / "results").rglob("*.md")),
             *sorted(SCENES.rglob("*.toml")), *sorted(SCENES.rglob("*.xml"))]
    return [f for f in files if f.is_file()]


def test_the_detector_finds_what_it_looks_for():
    assert _findings("as measured in issue 17") == ["issue 17"]
    assert _findings("(issues 17, 27)") == ["issues 17, 27"]
    assert _findings("see #12 (#12)") == ["(#12)"]
    assert _findings("the plate read 12 of 19 frames; sha256 " + "ab" * 32) == []
    if COMMITS:
        assert _findings(f"fixed at {COMMITS[-1][:9]}") == [f"commit {COMMITS[-1][:9]}"]


@pytest.mark.parametrize("path", _user_files(), ids=lambda p: str(p.relative_to(ROOT)))
def test_no_history_in_shipped_text(path):
    bad = []
    for n, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        bad += [f"{path.relative_to(ROOT)}:{n}: {f}" for f in _findings(line)]
    assert not bad, "\n".join(bad)


def test_no_history_in_command_help():
    texts = []
    for cmd in [None, *COMMANDS]:
        args = [sys.executable, "-m", "poevp_optics.cli"] + ([cmd] if cmd else []) + ["--help"]
        done = subprocess.run(args, capture_output=True, text=True, timeout=120, cwd=ROOT)
        assert done.returncode == 0, (cmd, done.stderr[-500:])
        texts.append((cmd or "poevp", done.stdout))
    bad = [f"{cmd}: {f}" for cmd, text in texts for f in _findings(text)]
    assert not bad, bad


def test_no_history_in_a_rendered_report(tmp_path):
    """The default scene at 1/24 of its mirrors: its description, notes and labels as a user
    sees them in report.html and report.json."""
    from poevp_optics.cli import main

    out = tmp_path / "run"
    assert main(["render", str(SCENES / "night_road"), "--out", str(out), "--quiet",
                 "--set", "render.resolution=[45,80]", "--set", "objective.focal_length_m=0.002878",
                 "--set", "mask.smooth_px=1.0", "--set", "attenuator.serve_min_mirrors=6",
                 "--set", "render.spp=2", "--set", "render.roi_spp=0", "--set", "timing.frames=3"]) == 0
    page = (out / "report.html").read_text()
    report = json.dumps(json.loads((out / "report.json").read_text()))
    assert "Night road" in page                       # the scene's description is on the page
    bad = [f"report.html: {f}" for f in _findings(page)] + [f"report.json: {f}" for f in _findings(report)]
    assert not bad, bad
    assert "camera_offset_m from" not in page          # no key name standing in for its value
