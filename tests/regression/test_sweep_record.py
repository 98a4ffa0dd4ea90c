"""A sweep is its scene, grid and inputs (issue 14): a sweep stopped by an exception resumes
without recomputing, under another name of its scene and with its grid flags in another order;
an edited scene or other overrides are refused on resume; failed points make the exit 1."""

from __future__ import annotations

import hashlib
import json
import shutil

import pandas as pd

from poevp_optics.apps.sweep import sweep as sweep_mod
from poevp_optics.cli import main
from tests.conftest import SCENES

SMALL = ["--set", "render.resolution=[24,32]", "--set", "timing.frames=2", "--set", "render.spp=4",
         "--set", "outputs.previews=false", "--set", "outputs.contact_sheet=false",
         "--workers", "2", "--quiet"]


def _points(out):
    """Every finished point folder: name -> {file: sha256}."""
    return {p.name: {str(f.relative_to(p)): hashlib.sha256(f.read_bytes()).hexdigest()
                     for f in sorted(p.rglob("*")) if f.is_file()}
            for p in sorted((out / "points").iterdir()) if p.is_dir()}


def test_sweep_resume_rules(tmp_path, capsys, monkeypatch):
    scene = tmp_path / "scene"
    scene.mkdir()
    for f in ("scene.toml", "scene.xml"):
        shutil.copy(SCENES / "smoke" / f, scene / f)
    out = tmp_path / "sw"
    # 0.05 s exposure does not fit a 1/30 s frame: those two points fail
    grid = ["--grid", "timing.exposure_s=0.01,0.05", "--grid", "mask.target=0.3,0.6"]
    real, calls = sweep_mod.write_table, []

    def failing(rows, folder):                  # the driver dies after two recorded points
        calls.append(len(rows))
        if len(calls) == 3:
            raise RuntimeError("disk on fire")
        return real(rows, folder)

    monkeypatch.setattr(sweep_mod, "write_table", failing)
    capsys.readouterr()
    assert main(["sweep", str(scene), "--out", str(out), *grid, *SMALL]) == 1     # one line (issue 28)
    assert "RuntimeError: disk on fire" in capsys.readouterr().err
    monkeypatch.setattr(sweep_mod, "write_table", real)
    recorded = pd.read_parquet(out / "results.parquet")
    assert len(recorded) == 2
    done = {k: v for k, v in _points(out).items()            # recorded points that ran ok
            if k.rsplit("-s", 1)[0] in set(recorded["point_key"])}
    record = json.loads((out / "sweep.json").read_text())
    assert set(record["inputs_sha256"]) >= {str((scene / f).resolve()) for f in ("scene.toml", "scene.xml")}
    # resumed through the .toml path with the grid flags in another order: the same sweep; the
    # finished points are kept as they were, the two others run; failed points: exit 1
    reordered = ["--grid", "mask.target=0.3,0.6", "--grid", "timing.exposure_s=0.01,0.05"]
    capsys.readouterr()
    assert main(["sweep", str(scene / "scene.toml"), "--out", str(out), *reordered, *SMALL]) == 1
    io = capsys.readouterr()
    assert "2 already finished, 2 to run" in io.out and "2 sweep points failed" in io.err
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 4 and (df["status"] == "failed").sum() == 2
    assert {k: v for k, v in _points(out).items() if k in done} == done
    assert not list((out / "points").glob(".*.staging-*")) and not list(tmp_path.glob(".sw.*"))
    stamps = _points(out)
    assert main(["sweep", str(scene), "--out", str(out), *grid, *SMALL, "--allow-failed"]) == 0
    assert "4 already finished, 0 to run" in capsys.readouterr().out
    # the scene changed since the sweep started: refused, one line naming the file
    (scene / "scene.xml").write_text((scene / "scene.xml").read_text() + "<!-- edited -->\n")
    before = (out / "results.parquet").read_bytes()
    assert main(["sweep", str(scene), "--out", str(out), *grid, *SMALL]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "scene.xml changed" in err, err
    # so is a different --set (the effective scene differs)
    shutil.copy(SCENES / "smoke" / "scene.xml", scene / "scene.xml")           # as it was
    assert main(["sweep", str(scene), "--out", str(out), *grid, *SMALL, "--set", "mask.smooth_px=2.0"]) == 2
    assert "the scene after --set overrides differs" in capsys.readouterr().err
    assert (out / "results.parquet").read_bytes() == before and _points(out) == stamps
