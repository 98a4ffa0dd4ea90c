"""benchmarks/loop_comparison.py runs `poevp compare` on each scene and gathers one table."""

from __future__ import annotations

from benchmarks import loop_comparison


def test_the_comparison_runs_and_writes_one_row_per_predictor_and_mode(tmp_path, monkeypatch):
    monkeypatch.setattr(loop_comparison, "output_folder", lambda results: tmp_path)
    loop_comparison.main(["--scenes", "smoke", "--predictors", "oracle,hold,track_net", "--modes", "open,demodulated"])
    rows = [line.split(" | ") for line in (tmp_path / "loop_comparison.md").read_text().splitlines()
            if line.startswith("| smoke |")]
    assert [(r[1], r[2]) for r in rows] == [("oracle", "-"), ("hold", "open"), ("hold", "demodulated"),
                                            ("track_net", "open"), ("track_net", "demodulated")]
    assert rows[0][3] == "1"                                       # the oracle's mask against itself
    assert (tmp_path / "loop" / "smoke" / "comparison.csv").is_file()
