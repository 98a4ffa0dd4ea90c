"""Radiance rendered once per sweep (apps/sweep/reuse.py, render/render_cache.py): a sweep over the
mask law's coefficients writes the same bytes whether its points share one render or each renders
its own, the table says which point rendered and which replayed, and a point whose render inputs
differ (render.spp) renders for itself."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from poevp_optics.cli import main
from tests.conftest import SCENES
from tests.regression.bit_identical import hash_outputs

#: smoke at 24x32, 2 frames: the mask law with coefficients (paper Eq. 2), the oracle loop
TINY = ["--set", "render.resolution=[24,32]", "--set", "timing.frames=2", "--set", "outputs.previews=false",
        "--set", "outputs.contact_sheet=false", "--set", "mask.law='threshold_exp'", "--set", "mask.vs=200.0",
        "--workers", "2", "--quiet"]
GRID = ["--grid", "mask.a=0.5,0.9", "--grid", "render.spp=4,6"]


def _points(out):
    """Point folder -> (hashes of its arrays and untimed report, untimed report)."""
    def untimed(obj):
        if isinstance(obj, dict):
            return {k: untimed(v) for k, v in obj.items() if "seconds" not in k and k != "render_reuse"}
        if isinstance(obj, list):
            return [untimed(v) for v in obj]
        return obj

    return {p.name: ({k: v for k, v in hash_outputs(p).items() if k != "report.json"},
                     untimed(json.loads((p / "report.json").read_text())))
            for p in sorted((out / "points").iterdir()) if p.is_dir()}


@pytest.mark.slow
def test_mask_sweep_reusing_the_render_equals_rendering_every_point(tmp_path, capsys):
    shared, every = tmp_path / "shared", tmp_path / "every"
    assert main(["sweep", str(SCENES / "smoke"), *GRID, *TINY, "--out", str(shared)]) == 0
    text = capsys.readouterr().out
    assert "4 runs share 2 renders" in text and "2 points render first; 2 wait for their render" in text
    assert main(["sweep", str(SCENES / "smoke"), *GRID, *TINY, "--out", str(every), "--no-reuse-render"]) == 0
    assert "share" not in capsys.readouterr().out
    a, b = _points(shared), _points(every)
    assert len(a) == 4 and a == b                              # bit-identical arrays, same reports
    df = pd.read_parquet(shared / "results.parquet")
    stable = [c for c in pd.read_parquet(every / "results.parquet").columns if "seconds" not in c]
    pd.testing.assert_frame_equal(df[stable], pd.read_parquet(every / "results.parquet")[stable])
    assert not (every / "renders").exists() and "render_key" not in pd.read_parquet(every / "results.parquet")
    # one render per spp: the mask coefficient shares it, the spp does not
    keys = df.groupby("grid.render.spp")["render_key"].nunique()
    assert keys.to_dict() == {4: 1, 6: 1} and df["render_key"].nunique() == 2
    for _, g in df.groupby("grid.render.spp"):
        leader = g[~g["render_reused"]]
        assert len(leader) == 1 and g["render_reused"].sum() == 1
        folder = f"{leader['point_key'].iloc[0]}-s0"
        assert (g["render_by"] == folder).all()
    stored = sorted(p.name for p in (shared / "renders").iterdir())
    assert stored == sorted(df["render_key"].unique())
    for p in (shared / "points").iterdir():
        report = json.loads((p / "report.json").read_text())
        assert report["render_reuse"]["key"] in stored
