"""Report extensions (apps/run/report_extensions.py): the generic run imports no scene-specific
report; a registered extension is called once per frame, before or after the loop observes the
frame, and once at the end, and its entries land in report.json."""

from __future__ import annotations

import ast
import json
from pathlib import Path

from poevp_optics.apps.run.report_extensions import REPORT_EXTENSIONS, ReportExtension
from poevp_optics.cli import main
from tests.conftest import SCENES

RUN = Path(__file__).resolve().parents[2] / "poevp_optics" / "apps" / "run" / "render_run.py"


def test_generic_run_imports_no_scene_report():
    names = set()
    for node in ast.walk(ast.parse(RUN.read_text())):
        if isinstance(node, ast.ImportFrom):
            names |= {f"{node.module}.{a.name}" for a in node.names}
        elif isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
    assert not [n for n in names if "night_road" in n], names
    assert "night_road" not in RUN.read_text().replace("report_extensions", "")


def test_a_registered_extension_runs_per_frame_and_at_the_end(tmp_path):
    calls = {"start": 0, "frames": [], "after": []}

    def start(spec):
        calls["start"] += 1
        return {"seen": 0}

    def frame(spec, camera, fc, step, state):
        state["seen"] += 1
        calls["frames"].append(fc.exposure.index)
        return {"frame": fc.exposure.index, "seen": state["seen"]}

    def after(spec, camera, fc, step, state):
        calls["after"].append(fc.exposure.index)
        return fc.exposure.index * 10

    def finish(spec, camera, report, out_dir, write_images):
        report["probe_summary"] = {"frames": len(report["per_frame"])}

    REPORT_EXTENSIONS.register("probe", ReportExtension("probe", lambda spec, causal: True, start, frame, finish),
                               source="test")
    REPORT_EXTENSIONS.register("probe_after", ReportExtension("probe_after", lambda spec, causal: True, frame=after,
                                                              after_observe=True), source="test")
    try:
        out = tmp_path / "run"
        assert main(["render", str(SCENES / "smoke"), "--out", str(out), "--quiet", "--frames", "3",
                     "--spp", "2", "--resolution", "16x24"]) == 0
    finally:
        REPORT_EXTENSIONS.unregister("probe")
        REPORT_EXTENSIONS.unregister("probe_after")
    r = json.loads((out / "report.json").read_text())
    assert calls["start"] == 1 and calls["frames"] == [0, 1, 2] and calls["after"] == [0, 1, 2]
    assert [f["probe"] for f in r["per_frame"]] == [{"frame": i, "seen": i + 1} for i in range(3)]
    assert [f["probe_after"] for f in r["per_frame"]] == [0, 10, 20]
    assert r["probe_summary"] == {"frames": 3}


def test_night_road_extension_applies_only_to_road_scenes():
    from poevp_optics.scene.load import load_scene

    ext = REPORT_EXTENSIONS["night_road"]
    assert ext.applies(load_scene(SCENES / "night_road"), True)
    assert not ext.applies(load_scene(SCENES / "smoke"), True)
