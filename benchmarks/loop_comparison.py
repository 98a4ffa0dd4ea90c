"""Closed-loop comparison on the default scene, two held-out sequences and the reversal case.

Runs `poevp compare` (one render per scene; oracle, hold, flow, track, track_net, dmvfn_lite x open,
raw, demodulated) at the scenes' default settings and collects one summary table
(loop_comparison.md, and each scene's comparison in loop/<scene>/, under out/benchmarks/ or, with
--results, benchmarks/results/).

    .venv/bin/python -m benchmarks.loop_comparison [--scenes highbeam_plate,heldout_swerve,...] [--results]
"""

from __future__ import annotations

import argparse

from benchmarks.common import ROOT, add_results_flag, machine_line, markdown_table, output_folder, save_text

SCENES = ["highbeam_plate", "heldout_swerve", "heldout_receding", "reversal"]


def main(argv=None):
    from poevp_optics.core import runtime
    from poevp_optics.apps.run.compare import COLUMNS, compare
    from poevp_optics.core.io import staged_dir
    from poevp_optics.scene.load import load_scene

    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--predictors", default="oracle,hold,flow,track,track_net,dmvfn_lite")
    ap.add_argument("--modes", default="open,raw,demodulated")
    add_results_flag(ap)
    args = ap.parse_args(argv)
    dest = output_folder(args.results)
    runtime.set_threads(2)
    rows = []
    for scene in args.scenes.split(","):
        out = dest / "loop" / scene
        with staged_dir(out, kind="compare") as stage:
            for r in compare(load_scene(ROOT / "scenes" / scene), args.predictors.split(","), args.modes.split(","),
                             stage, progress=False):
                rows.append([scene] + [r[c] for c in COLUMNS])
        print(f"done {scene}", flush=True)
    header = ["scene"] + COLUMNS
    text = (f"# Closed loop: predictors x loop modes\n\nDefault settings of each scene; per-scene "
            f"tables and figures in `loop/<scene>/`. Machine: {machine_line()}.\n\n"
            f"{markdown_table(header, [[('-' if v is None else v) for v in r] for r in rows])}\n")
    print(text)
    save_text(dest / "loop_comparison.md", text)


if __name__ == "__main__":
    main()
