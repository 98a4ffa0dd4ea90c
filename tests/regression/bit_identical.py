"""Bit-identical outputs of four small runs: the guard of behaviour-preserving refactors.

Every output array (EXR channels, PNG pixels, NPY) and `report.json` (without its timing and
machine fields) of `smoke`, `highbeam_plate` (92x160, 4 frames), `led_flicker` (46x80) and the
`dr_chart36` chart (160x160) is hashed. `tests/regression/test_bit_identical.py` compares a fresh
run with `reference_hashes.json`.

The references change only when the physics or the numerics change on purpose: regenerate them
with `python -m tests.regression.bit_identical --write "reason"` and say why in the commit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REFERENCE = HERE / "reference_hashes.json"
SCENES = HERE.parent.parent / "scenes"

CASES = {
    "smoke": ["render", "smoke"],
    "highbeam_plate": ["render", "highbeam_plate", "--resolution", "92x160", "--frames", "4", "--spp", "4",
                       "--set", "render.subframes=3"],
    "led_flicker": ["render", "led_flicker", "--resolution", "46x80", "--frames", "2", "--spp", "4"],
    "dr_chart36": ["chart", "dr_chart36", "--resolution", "160x160", "--spp", "4",
                   "--set", "chart.repeats=4", "--set", "chart.roi_inset_px=2"],
}

#: report.json keys that measure time or describe the machine, not the physics.
VOLATILE = ("seconds", "scene_file", "variant", "libllvm", "version", "cameras")


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if not any(t in k for t in VOLATILE)}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _array_hash(a: np.ndarray) -> str:
    a = np.ascontiguousarray(a)
    return hashlib.sha256(f"{a.dtype.str}{a.shape}".encode() + a.tobytes()).hexdigest()[:16]


def hash_outputs(folder: Path) -> dict:
    from poevp_optics.core.io import read_exr, read_png

    out = {}
    for f in sorted(p for p in folder.rglob("*") if p.is_file()):
        rel = str(f.relative_to(folder))
        if f.name.startswith("."):
            continue
        if f.suffix == ".exr":
            chans, _ = read_exr(f)
            for c in sorted(chans):
                out[f"{rel}:{c}"] = _array_hash(chans[c])
        elif f.suffix == ".png" and "curves" not in f.name and "plot" not in f.name:
            out[rel] = _array_hash(read_png(f))          # matplotlib figures embed versions: skipped
        elif f.suffix == ".npy":
            out[rel] = _array_hash(np.load(f))
        elif f.name == "report.json":
            text = json.dumps(_strip(json.loads(f.read_text())), sort_keys=True)
            out[rel] = hashlib.sha256(text.encode()).hexdigest()[:16]
        elif f.suffix == ".csv":
            out[rel] = hashlib.sha256(f.read_bytes()).hexdigest()[:16]
    return out


def run_case(name: str, root: Path) -> dict:
    from poevp_optics.cli import main

    job, scene, *rest = CASES[name]
    out = root / name
    rc = main([job, str(SCENES / scene), "--out", str(out), "--quiet", *rest])
    if rc != 0:
        raise RuntimeError(f"{name}: poevp {job} exited {rc}")
    return hash_outputs(out)


def main(argv=None) -> int:
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", metavar="REASON", help="rewrite reference_hashes.json, giving the reason")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        hashes = {name: run_case(name, Path(tmp)) for name in CASES}
    if args.write:
        REFERENCE.write_text(json.dumps({"reason": args.write, "cases": hashes}, indent=1, sort_keys=True) + "\n")
        print(f"wrote {REFERENCE}")
        return 0
    ref = json.loads(REFERENCE.read_text())["cases"]
    bad = [f"{c}/{k}" for c in ref for k in set(ref[c]) | set(hashes[c]) if ref[c].get(k) != hashes[c].get(k)]
    print("\n".join(bad) or "identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
