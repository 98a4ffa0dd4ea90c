"""Generate the data of the two frame-source example scenes from `scenes/highbeam_plate`.

    PYTHONPATH=$PWD .venv/bin/python scripts/make_source_examples.py

* `scenes/exr_highbeam/frames/`: the highbeam_plate night road rendered once by Mitsuba at
  46x80, as a 120 fps sequence of sensor-weighted photon radiance (EXR channel Y, float32,
  e- s-1 m-2 sr-1; frame j at t = j / 120 s, one render of 64 spp each), and `boxes.csv` (the
  plate's image box per frame, and its text).
* `scenes/ldr_highlight_demo/frames/`: an ordinary LDR video of the same road at 288x512, 30 fps,
  8 frames, the car ahead crossing at `LDR_LATERAL_M_PER_S` (2 m/s, a lane change; ~15 px/frame,
  so a mask that does not follow the plate misses it) while we close at 6 m/s:
  each frame is the exposure-centre radiance through a fixed linear camera whose white (8-bit
  255) is 1.25 x the brightest plate pixel of the sequence, sRGB-encoded (IEC 61966-2-1) as 8-bit
  grey PNG; `boxes.csv` holds the plate box and text per frame. The scene adds the paper's
  highlight (Eq. 3) on top.

The output is committed (about 0.6 MB; `--ldr-only` remakes only the LDR demo): the example scenes then run without Mitsuba and without
this script, and give the same numbers everywhere; the renders are seeded, so rerunning this
script reproduces the files. No downloads.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from poevp_optics.camera.camera import Camera
from poevp_optics.core.io import atomic_path, write_exr, write_png
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT
from poevp_optics.render.radiance import open_source
from poevp_optics.scene.load import load_scene

ROOT = Path(__file__).resolve().parent.parent
SCENE = ROOT / "scenes" / "highbeam_plate"


def _box_row(j: int, roi, text: str) -> str:
    y0, x0, y1, x1 = roi
    return f"{j},{x0},{y0},{x1},{y1},{text}\n"


#: Scene radiance on the sensor grid, no guard band (the relay is the camera's, not the scene's).
DELTA = ('relay.psf="delta"',)

#: The LDR demo's lateral speed of the car ahead (m/s, to image left): a lane change. A 144x256,
#: 0.6 m/s demo (3 px/frame, a 13 px tall plate) was too small for the OCR and too slow to tell
#: a predictor from `hold`.
LDR_LATERAL_M_PER_S = 2.0


def _frames(size: tuple[int, int], times_s, spp: int, extra: tuple[str, ...] = ()):
    """(radiance on the sensor grid, plate box) at each time, rendered by the Mitsuba source."""
    spec = load_scene(SCENE, [f"render.resolution=[{size[0]},{size[1]}]", f"render.spp={spp}", *DELTA, *extra])
    src = open_source(spec, guard_px=0)
    for j, t in enumerate(times_s):
        src.set_time(float(t))
        seeds = np.random.SeedSequence([spec.render.seed, 9000, j]).generate_state(spec.render.mc_splits)
        mean, _ = src.render_with_error([int(x & 0x7FFFFFFF) for x in seeds], spp)
        yield mean, src.roi_box()


def make_exr(out: Path, fps: float = 120.0, n: int = 13, size=(46, 80), spp: int = 64) -> None:
    text = load_scene(SCENE).plate.text
    rows = []
    for j, (img, roi) in enumerate(_frames(size, np.arange(n) / fps, spp)):
        write_exr(out / "frames" / f"road_{j:04d}.exr", {"Y": img},
                  {"poevp_quantity": "sensor-weighted photon radiance (IMX253 QE)",
                   "poevp_unit": PHOTON_RADIANCE_UNIT, "poevp_t_s": repr(j / fps),
                   "poevp_source": "scenes/highbeam_plate rendered by scripts/make_source_examples.py"})
        if roi is not None:
            rows.append(_box_row(j, roi, text))
    with atomic_path(out / "frames" / "boxes.csv") as tmp:
        tmp.write_text("frame,x0,y0,x1,y1,text\n" + "".join(rows))


def srgb_encode(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values in [0, 1]."""
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * v ** (1 / 2.4) - 0.055)


def make_ldr(out: Path, fps: float = 30.0, n: int = 8, size=(288, 512), spp: int = 16) -> None:
    spec = load_scene(SCENE)
    t_mid = np.arange(n) / fps + spec.timing.exposure_offset_s + spec.timing.exposure_s / 2
    frames = list(_frames(size, t_mid, spp, (f"motion.plate.velocity_m_per_s=[{-LDR_LATERAL_M_PER_S}, 0.0, -6.0]",)))
    plate_max = max(float(img[r[0]:r[2], r[1]:r[3]].max()) for img, r in frames if r is not None)
    white = 1.25 * plate_max
    rows = []
    for j, (img, roi) in enumerate(frames):
        code = np.rint(255.0 * srgb_encode(img / white)).astype(np.uint8)
        write_png(out / "frames" / f"road_{j:04d}.png", code)
        if roi is not None:
            rows.append(_box_row(j, roi, spec.plate.text))
    with atomic_path(out / "boxes.csv") as tmp:
        tmp.write_text("frame,x0,y0,x1,y1,text\n" + "".join(rows))


if __name__ == "__main__":
    assert Camera.from_scene(load_scene(SCENE, list(DELTA))).guard_px == 0, "the examples assume highbeam_plate's delta relay"
    if "--ldr-only" not in sys.argv:
        make_exr(ROOT / "scenes" / "exr_highbeam")
    make_ldr(ROOT / "scenes" / "ldr_highlight_demo")
    for d in ("exr_highbeam", "ldr_highlight_demo"):
        size = sum(f.stat().st_size for f in (ROOT / "scenes" / d).rglob("*") if f.is_file())
        print(f"scenes/{d}: {size / 1024:.0f} KiB")
