"""Training data from the simulator itself: procedurally varied plate sequences, rendered and
passed through the LDR camera (DMD white, IMX253 8-bit, noise on), cached as a small .npz.

Varied per sequence (seeded): plate text, lateral and closing speed (direction), start distance
and lateral offset, high-beam intensity, exposure time. Frames are at the predictor resolution.

The cache is keyed on everything the frames depend on (`dataset_key`): the draw parameters, the
SHA-256 of every file the scene reads (scene.toml, scene.xml, spectra, meshes, textures), the
resolved camera, the generator's own version, the package's, Mitsuba's and DrJit's.
"""

from __future__ import annotations

import json
import os
import string
from pathlib import Path

import numpy as np
from poevp_optics.core.paths import REPO_ROOT, SCENES_DIR

SCENE = SCENES_DIR / "highbeam_plate"
#: Version of what this module draws and renders per sequence (`sequence_overrides`,
#: `render_ldr_sequence`): raised whenever either changes what a sequence holds.
GENERATOR_VERSION = 2
LETTERS = string.ascii_uppercase.replace("I", "").replace("O", "")


def random_plate_text(rng: np.random.Generator) -> str:
    return (f"{''.join(rng.choice(list(LETTERS), 2))} {rng.integers(0, 10)}"
            f"{''.join(rng.choice(list(LETTERS + string.digits), 4))}")


def sequence_overrides(rng: np.random.Generator, resolution=(368, 640)) -> list[str]:
    """One sequence's scene overrides: drawn plate, motion, beams and exposure (8-33 ms). The DMD
    is held all white here (an LDR camera), so no bit-plane is ever shown and the scene's DLPC900
    limit (an 8-bit window of >= 26.8 ms, camera/dmd.py) does not apply: the `ideal` controller
    lets the window follow the drawn exposure."""
    vx = float(rng.uniform(-2.0, 2.0))
    vz = float(rng.uniform(-12.0, 3.0))
    x0 = float(rng.uniform(-0.7, 0.7))
    z0 = float(rng.uniform(-3.0, 8.0))
    cd = float(rng.uniform(4e4, 2.5e5))
    exp_s = float(rng.uniform(0.008, 0.033))
    return [f"plate.text={json.dumps(random_plate_text(rng))}",
            f"motion.plate.velocity_m_per_s=[{vx}, 0.0, {vz}]",
            f"motion.plate.start_offset_m=[{x0}, 0.0, {z0}]",
            f"spectra.highbeam.intensity_cd={cd}",
            f"timing.exposure_s={exp_s}", f"timing.dmd_window_s={exp_s}", "dmd.controller='ideal'",
            f"render.resolution=[{resolution[0]}, {resolution[1]}]",
            "render.subframes=1", "render.spp=4", "render.mc_splits=2"]


def render_ldr_sequence(overrides: list[str], frames: int, seed: int) -> np.ndarray:
    """(frames, H, W) uint8 LDR captures of the default scene under `overrides`."""
    from poevp_optics.camera.camera import Camera
    from poevp_optics.analysis.metrics import to_8bit
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.scene.load import load_scene
    spec = load_scene(SCENE, [*overrides, f"timing.frames={frames}", f"render.seed={seed}"])
    cam = Camera.from_params(spec.resolved.camera)
    r = Renderer(spec.resolved.render, guard_px=cam.guard_px)
    out = []
    white = cam.white_mask()
    for i in range(frames):
        r.set_time(float(spec.subframe_times_s(i)[0]))
        rad = r.render_once(seed * 1000 + i, spec.render.spp)
        cap = cam.capture([rad], white, i, seed * 1000 + i)
        out.append(to_8bit(cap.dn, cam.params.max_dn).astype(np.uint8))
    return np.stack(out)


def cache_dir() -> Path:
    from poevp_optics.core import runtime

    return runtime.cache_dir("predictor_data")


def dataset_key(n_sequences: int, frames: int, seed: int, resolution=(368, 640)) -> tuple[str, dict]:
    """(key, parts): the first 16 hex of the SHA-256 of everything a data set's frames depend
    on, and those parts: draw parameters, the scene's files (name -> SHA-256, named relative to
    the scene's folder or else the repository, so the key is the same on every clone), the
    resolved camera, and the
    generator, package, Mitsuba and DrJit versions."""
    import drjit as dr
    import mitsuba as mi

    from poevp_optics import __version__
    from poevp_optics.apps.sweep.bundle import scene_inputs, with_hashes
    from poevp_optics.core.cache import json_digest
    from poevp_optics.scene.load import load_scene

    spec = load_scene(SCENE, cross_checks=False)
    cam = spec.resolved.camera
    camera = repr(cam).replace(repr(cam.base_dir), "<scene folder>")     # the same camera in any folder
    files = {}
    for r in with_hashes(scene_inputs(spec)):
        src = Path(r.source).resolve()
        for root in (Path(SCENE).resolve(), REPO_ROOT):
            if src.is_relative_to(root):
                files[src.relative_to(root).as_posix()] = r.sha256
                break
        else:
            files[src.name] = r.sha256
    parts = {"sequences": int(n_sequences), "frames": int(frames), "seed": int(seed),
             "resolution": [int(v) for v in resolution], "scene": SCENE.name,
             "scene_files_sha256": dict(sorted(files.items())), "camera": camera,
             "generator": GENERATOR_VERSION, "poevp_optics": __version__, "mitsuba": mi.__version__,
             "drjit": dr.__version__}
    return json_digest(parts, algo="sha256", sort_keys=True), parts


def build_dataset(n_sequences: int, frames: int, seed: int, resolution=(368, 640),
                  progress: bool = True) -> np.ndarray:
    """(N, T, H, W) uint8, cached by its parameters."""
    from tqdm import tqdm

    from poevp_optics.core.cache import cached

    def build():
        rng = np.random.default_rng(seed)
        seqs = []
        for i in tqdm(range(n_sequences), desc="render training sequences", disable=not progress or None):
            seqs.append(render_ldr_sequence(sequence_overrides(rng, resolution), frames, seed * 100000 + i))
        return np.stack(seqs)

    def save(tmp, arr):
        with open(tmp, "wb") as f:
            np.savez_compressed(f, frames=arr)

    def load(p):
        with np.load(p) as z:
            return z["frames"]

    def problem(arr) -> str | None:
        want = (n_sequences, frames, int(resolution[0]), int(resolution[1]))
        return None if arr.dtype == np.uint8 and arr.shape == want else f"frames {arr.dtype} {arr.shape}, not uint8 {want}"

    key, _ = dataset_key(n_sequences, frames, seed, resolution)
    path = cache_dir() / f"seq_{key}.npz"
    return cached(path, build, load=load, save=save, check=problem)
