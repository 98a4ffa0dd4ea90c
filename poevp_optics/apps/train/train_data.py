"""`poevp train-data SCENE`: predictor training data rendered from any scene with a plate.

Each sequence moves the scene's plate (with everything attached to it: the car) along one motion
kind, with its own plate text, high-beam intensity, start distance and seeds, and is rendered
**per frame with the scene's own renderer** (Mitsuba, its lights, materials and geometry) and
captured by the scene's camera through an all-white mask (the LDR camera: 8-bit, sensor noise on).
Rendering per frame, not once per configuration and moved, because the motions change the range
(approaching/receding: the plate grows, its sheeting's return and the beam's falloff change) and
a moved 2-D image would not show that; and it is affordable: at the default training
resolution (184x320, 4 spp, one radiance node per frame at the exposure's midpoint: no motion
blur) a sequence of 8 frames took 1.7 s for highbeam_plate (360 in 610 s) and 3.4 s for
night_road (Double Gauss objective, IES lamps; 20 in 68 s) on this machine's 2 shared cores,
scene load and renderer set-up per sequence included.

Motion kinds (u = frames, v = image speed px/frame at the start range; image-plane paths from
analysis/motion_paths.py, converted to metres at the plate's range):

| kind         | image path                                   | range                       |
|--------------|----------------------------------------------|-----------------------------|
| approaching  | straight drift at v/4, any road heading      | closes at 3-12 m/s           |
| receding     | straight drift at v/4                        | opens at 3-12 m/s            |
| lateral      | straight, heading 0 or 180 deg (both ways)   | held                        |
| vertical     | straight, heading 90 or 270 deg              | held                        |
| curved, accelerating, braking, swerve, lane_change, reversal | motion_paths kind, heading 0/180 +- 30 deg | held |

3-12 m/s: the closing/opening speed of two cars in traffic (apps/evaluate/eval_sequences.py uses 12 m/s).
Range, lateral offset and image speed are converted with the scene's own geometry, measured on
the scene (`calibrate`: the plate's box at probe poses). Every path is centred on the plate's
own place in the scene (the beams' hot spot), slowed until it spans at most 80 % of the frame
and moved just enough to stay inside it.

Split: train / val / held-out test differ by seed streams (`SPLIT_SEEDS`), by plate texts (each
split's texts start with a letter of its own third of the alphabet, `SPLIT_LETTERS`: disjoint by
construction) and by trajectories (every parameter drawn from the split's seeds; the manifest
lists each sequence's draws). The data are cached by content: SHA-256 of every file the scene
reads (apps/sweep/bundle.py `scene_inputs`) and of the generation parameters names a folder under
the cache (`poevp_optics/train_data/<scene>-<hash>`); a second call with the same inputs reads
it without rendering. With a Dask scheduler the sequences render as points of the sweep
machinery (apps/sweep/sweep.py `_execute`: scene bundle, worker checks, retries), else in this process.
"""

from __future__ import annotations

import hashlib
import json
import string
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from poevp_optics import __version__
from poevp_optics.apps.train.train_render import JOB, render_frames
from poevp_optics.core.exceptions import SceneError

if TYPE_CHECKING:
    from poevp_optics.apps.sweep.sweep import ClusterSettings

DATA_KINDS = ("approaching", "receding", "lateral", "vertical", "curved", "accelerating", "braking",
              "lane_change", "swerve", "reversal")
SPLITS = ("train", "val", "test")
#: Seed offsets of the splits (disjoint streams; apart from apps/train/train_track.py's synthetic ones).
SPLIT_SEEDS = {"train": 10_000_000, "val": 11_000_000, "test": 12_000_000}
_LETTERS = string.ascii_uppercase.replace("I", "").replace("O", "")
#: First letters of each split's plate texts: disjoint thirds of the alphabet (no I, O).
SPLIT_LETTERS = {"train": _LETTERS[:8], "val": _LETTERS[8:16], "test": _LETTERS[16:]}
#: Closing / opening speeds (m/s) of approaching / receding sequences (module docstring).
RANGE_SPEED_M_PER_S = (3.0, 12.0)
DATA_VERSION = "train-data-v4"
#: Probe steps of `calibrate` (m): near the base pose, and at the far pose.
PROBE_M = 0.25
FAR_PROBE_M = 1.0


@dataclass(frozen=True)
class DataConfig:
    """What a data set is made of (all of it enters the content hash).

    sequences: per split (train, val, test); frames per sequence; resolution (H, W) px; spp;
    beam: high-beam intensity range, x the scene's; distance: start range, x the scene's
    plate range; speed: image speed range, fraction of the frame width per frame; seed."""

    sequences: tuple[int, int, int] = (96, 24, 24)
    frames: int = 8
    resolution: tuple[int, int] = (184, 320)
    spp: int = 4
    beam: tuple[float, float] = (0.5, 2.0)
    distance: tuple[float, float] = (0.5, 1.2)
    speed: tuple[float, float] = (0.006, 0.075)
    seed: int = 0

    def __post_init__(self):
        if len(self.sequences) != 3 or min(self.sequences) < 1:
            raise SceneError(f"--sequences {self.sequences}: three positive counts (train, val, test)")
        if self.frames < 4:
            raise SceneError(f"--frames {self.frames}: at least 4 (the tracker reads four frames)")
        if min(self.resolution) < 32:
            raise SceneError(f"--resolution {self.resolution}: at least 32 px each way")


@dataclass(frozen=True)
class SequenceDraw:
    """One sequence's draws (module docstring): kind, image speed (px/frame at the start
    range), heading (deg, image axes), turn (rad/frame, curved), start range (x the scene's),
    range speed (m/s, + away), beam (x the scene's), plate text, seed."""

    split: str
    index: int
    seed: int
    kind: str
    text: str
    speed_px: float
    heading_deg: float
    turn_rad: float
    range_scale: float
    range_speed_m_per_s: float
    beam_scale: float


def plate_text(rng: np.random.Generator, split: str) -> str:
    first = SPLIT_LETTERS[split]
    return (f"{first[int(rng.integers(len(first)))]}{_LETTERS[int(rng.integers(len(_LETTERS)))]} "
            f"{''.join(rng.choice(list(string.digits), 4))}")


def draw_sequence(split: str, index: int, cfg: DataConfig) -> SequenceDraw:
    seed = SPLIT_SEEDS[split] + 1000 * cfg.seed + index
    rng = np.random.default_rng(seed)
    kind = DATA_KINDS[int(rng.integers(len(DATA_KINDS)))]
    w = cfg.resolution[1]
    speed = float(np.exp(rng.uniform(np.log(cfg.speed[0] * w), np.log(cfg.speed[1] * w))))
    side = 180.0 * int(rng.integers(2))
    if kind == "lateral":
        heading = side
    elif kind == "vertical":
        heading = 90.0 + side
    else:
        heading = (side + float(rng.uniform(-30.0, 30.0))) % 360.0
    turn = float(rng.uniform(0.04, 0.25)) * (1 if rng.random() < 0.5 else -1)
    rs = float(rng.uniform(*RANGE_SPEED_M_PER_S))
    range_speed = -rs if kind == "approaching" else rs if kind == "receding" else 0.0
    return SequenceDraw(split, index, seed, kind, plate_text(rng, split), speed, heading, turn,
                        float(rng.uniform(*cfg.distance)), range_speed,
                        float(np.exp(rng.uniform(np.log(cfg.beam[0]), np.log(cfg.beam[1])))))


def draws(cfg: DataConfig) -> dict[str, list[SequenceDraw]]:
    return {s: [draw_sequence(s, i, cfg) for i in range(n)] for s, n in zip(SPLITS, cfg.sequences)}


# ----------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class Geometry:
    """The plate's image geometry at its base pose, measured on the scene: box centre (px),
    signed px per metre of x and y offset, range Z0 (m), frame (H, W)."""

    centre_px: tuple[float, float]
    px_per_m: tuple[float, float]
    range_m: float
    shape: tuple[int, int]


def _probe(spec, poses) -> list:
    """The plate's roi-box centres (x, y px) at `poses` (offsets, m); None where out of view."""
    from poevp_optics.apps.evaluate.eval_sequences import with_poses
    from poevp_optics.render.renderer import Renderer

    r = Renderer(with_poses(spec, tuple(float(t) for t in range(len(poses))), tuple(poses)).resolved.render)
    out = []
    for t in range(len(poses)):
        r.set_time(float(t))
        b = r.roi_box()
        out.append(None if b is None else ((b[1] + b[3]) / 2.0, (b[0] + b[2]) / 2.0))
    return out


def calibrate(spec) -> Geometry:
    """The plate's box centre at its base pose, px per metre of x and y offset from probes at
    -+PROBE_M, and its range Z0 from the x scale at dz = 20 m (or 5 m) farther, probed at
    -+FAR_PROBE_M (pinhole: p ~ 1/Z, Z0 = dz p1 / (p0 - p1)). Box edges are whole pixels: Z0 is
    good to about 20 % on a plate a few pixels tall (night_road at 184x320), enough to set the
    sequences' start ranges."""
    a = PROBE_M
    c = _probe(spec, ((0, 0, 0), (-a, 0, 0), (a, 0, 0), (0, -a, 0), (0, a, 0)))
    if any(v is None for v in c):
        raise SceneError(f"{spec.toml_path}: render.roi_shape: the plate leaves the frame at the probe poses")
    px_x, px_y = (c[2][0] - c[1][0]) / (2 * a), (c[4][1] - c[3][1]) / (2 * a)
    z0 = None
    for dz in (20.0, 5.0):          # far probe: most precise while the plate stays in view
        for b in (FAR_PROBE_M, a):
            f = _probe(spec, ((-b, 0, dz), (b, 0, dz)))
            if all(v is not None for v in f):
                p1 = (f[1][0] - f[0][0]) / (2 * b)
                if abs(px_x) - abs(p1) > 0.5 / b:
                    z0 = dz * abs(p1) / (abs(px_x) - abs(p1))
                    break
        if z0 is not None:
            break
    if z0 is None or abs(px_x) * a < 1.0:
        raise SceneError(f"{spec.toml_path}: render.roi_shape: the plate is too small at "
                         f"{spec.render.resolution} to measure its range; raise --resolution")
    return Geometry(c[0], (px_x, px_y if abs(px_y) * a >= 1.0 else -px_x), float(z0), tuple(spec.render.resolution))


def frame_times_s(spec, frames: int) -> np.ndarray:
    """Each frame's radiance time: the midpoint of its exposure window (s)."""
    return np.array([sum(spec.exposure_window_s(i)) / 2.0 for i in range(frames)])


def image_path(d: SequenceDraw, frames: int) -> np.ndarray:
    """(frames, 2) image offsets (px, x and y) of the plate at its start range."""
    from poevp_optics.analysis.motion_paths import PathSpec, centres

    kind = {"approaching": "straight", "receding": "straight", "lateral": "straight",
            "vertical": "straight"}.get(d.kind, d.kind)
    v = d.speed_px / 4.0 if d.kind in ("approaching", "receding") else d.speed_px
    return centres(PathSpec(kind, v, d.heading_deg, frames, d.turn_rad), np.arange(frames, dtype=float))


def offsets_m(d: SequenceDraw, geo: Geometry, times_s: np.ndarray, frames: int) -> np.ndarray:
    """(frames, 3) plate offsets (m) of sequence `d`: the image path slowed until it fits 80 %
    of the frame, centred on the plate's own place in the scene (where the scene's beams light
    it: a road scene's plate moved to the frame's centre leaves the beam's hot spot) and moved
    only as far as needed to stay within 10-90 % of the frame, at a range moving at
    d.range_speed_m_per_s."""
    h, w = geo.shape
    path = image_path(d, frames)
    ext = path.max(0) - path.min(0)
    shrink = min(1.0, 0.8 * w / max(ext[0], 1e-9), 0.8 * h / max(ext[1], 1e-9))
    path = path * shrink
    path = path - (path.max(0) + path.min(0)) / 2
    c0, size = np.asarray(geo.centre_px, float), np.array([w, h], float)
    lo, hi = c0 + path.min(0), c0 + path.max(0)
    path = path + np.maximum(0.1 * size - lo, 0) - np.maximum(hi - 0.9 * size, 0)
    z_start = geo.range_m * d.range_scale
    z = z_start + d.range_speed_m_per_s * (times_s - times_s[0])
    z = np.maximum(z, 0.3 * geo.range_m)
    scale = z / geo.range_m          # px per m falls as 1/Z: keep the image path
    x = path[:, 0] / geo.px_per_m[0] * scale
    y = path[:, 1] / geo.px_per_m[1] * scale
    return np.stack([x, y, z - geo.range_m], axis=1)


def sequence_overrides(spec, d: SequenceDraw, cfg: DataConfig, geo: Geometry) -> list[str]:
    """The scene overrides that make sequence `d` (motion as keyframes of the plate)."""
    from poevp_optics.apps.evaluate.eval_sequences import plate_motion

    ident, attached = plate_motion(spec)
    times = frame_times_s(spec, cfg.frames)
    offs = offsets_m(d, geo, times, cfg.frames)
    ov = [f"render.resolution={list(cfg.resolution)}", f"render.spp={cfg.spp}", "render.subframes=1",
          "render.pwm_nodes=false", f"timing.frames={cfg.frames}", f"plate.text={json.dumps(d.text)}",
          f"render.seed={d.seed}", "outputs.previews=false",
          "outputs.contact_sheet=false", "outputs.radiance_exr=false",
          f"motion.{ident}.kind='keyframes'", f"motion.{ident}.start_offset_m=[0.0, 0.0, 0.0]",
          f"motion.{ident}.velocity_m_per_s=[0.0, 0.0, 0.0]",
          f"motion.{ident}.times_s={json.dumps([round(float(t), 9) for t in times])}",
          f"motion.{ident}.offsets_m={json.dumps(np.round(offs, 6).tolist())}",
          f"motion.{ident}.attached={json.dumps(list(attached))}"]
    beam = spec.spectra.get("highbeam")
    if beam is not None and np.isfinite(getattr(beam, "intensity_cd", float("nan"))):
        ov.append(f"spectra.highbeam.intensity_cd={beam.intensity_cd * d.beam_scale:.6g}")
    return ov


# ----------------------------------------------------------------------------- data set
@dataclass
class TrainData:
    """A built data set: its folder, manifest, and per split frames (N, T, H, W) uint8, plate
    boxes (N, T, 4) and draws."""

    folder: Path
    manifest: dict
    splits: dict = field(default_factory=dict)
    rendered: bool = False

    @property
    def sha256(self) -> str:
        return self.manifest["content_sha256"]


def content_key(scene: str, cfg: DataConfig) -> tuple[str, dict]:
    """SHA-256 of every file the scene reads and of the generation parameters; and the parts."""
    from poevp_optics.apps.sweep.bundle import scene_inputs, with_hashes
    from poevp_optics.scene.load import load_scene

    spec = load_scene(scene, cross_checks=False)
    files = {r.source: r.sha256 for r in with_hashes(scene_inputs(spec))}
    parts = {"scene_files_sha256": {k: files[k] for k in sorted(files)}, "config": asdict(cfg),
             "version": DATA_VERSION, "poevp_optics": __version__}
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=list).encode()).hexdigest(), parts


def data_folder(scene: str, key: str) -> Path:
    from poevp_optics.core.runtime import cache_dir
    from poevp_optics.scene.load import resolve_scene_path

    return cache_dir("train_data") / f"{resolve_scene_path(scene).parent.name}-{key[:16]}"


def _data_problem(data: TrainData, key: str, cfg: DataConfig) -> str | None:
    """Why a loaded data set is not the one `key` and `cfg` name (its manifest's hash, each
    split's frames (N, T, H, W) uint8, boxes (N, T, 4) and draws), or None."""
    if data.manifest.get("content_sha256") != key:
        return f"manifest.json names data set {str(data.manifest.get('content_sha256'))[:12]}, not {key[:12]}"
    for s, n in zip(SPLITS, cfg.sequences):
        frames, boxes = data.splits[s]["frames"], data.splits[s]["boxes"]
        want = (n, cfg.frames, *cfg.resolution)
        if frames.dtype != np.uint8 or frames.shape != want:
            return f"{s}.npz: frames {frames.dtype} {frames.shape}, not uint8 {want}"
        if boxes.shape != (n, cfg.frames, 4) or len(data.splits[s]["draws"]) != n:
            return f"{s}.npz: boxes {boxes.shape} and {len(data.splits[s]['draws'])} draws, not ({n}, {cfg.frames}, 4) and {n}"
    return None


def _verified_data(folder: Path, key: str, cfg: DataConfig) -> TrainData:
    """`load_data(folder)` once the manifest and each split pass their checksums (core/cache.py)
    and `_data_problem` finds nothing; CacheCheckError with the reason otherwise."""
    from poevp_optics.core.cache import NO_CHECKSUM, CacheCheckError, UncheckedFile, checksum_problem

    for name in ("manifest.json", *(f"{s}.npz" for s in SPLITS)):
        problem = checksum_problem(folder / name)
        if problem is not None:
            raise (UncheckedFile if problem == NO_CHECKSUM else CacheCheckError)(f"{name}: {problem}")
    try:
        data = load_data(folder)
        problem = _data_problem(data, key, cfg)
    except Exception as e:                       # noqa: BLE001 - whatever a damaged file makes load raise
        raise CacheCheckError(f"{type(e).__name__}: {' '.join(str(e).split())[:200]}") from e
    if problem is not None:
        raise CacheCheckError(problem)
    return data


def load_data(folder: Path) -> TrainData:
    manifest = json.loads((folder / "manifest.json").read_text())
    out = TrainData(folder, manifest)
    for s in SPLITS:
        z = np.load(folder / f"{s}.npz")
        out.splits[s] = {"frames": z["frames"], "boxes": z["boxes"],
                         "draws": [SequenceDraw(**d) for d in manifest["sequences"][s]]}
    return out


def build_data(scene: str, cfg: DataConfig = DataConfig(), *, cluster: ClusterSettings | None = None,
               progress: bool = True, log=print) -> TrainData:
    """Render (or find in the cache) the three splits of `scene` under `cfg`: in this process, or
    on the Dask cluster `cluster` names (apps/sweep/sweep.py ClusterSettings with a scheduler)."""
    from poevp_optics.core.cache import CacheCheckError, UncheckedFile, discard, note_rebuilt, write_checksum
    from poevp_optics.core.io import atomic_path, write_json
    from poevp_optics.scene.load import load_scene, resolve_scene_path

    key, parts = content_key(scene, cfg)
    folder = data_folder(scene, key)
    damaged = None
    if (folder / "manifest.json").is_file():
        try:
            data = _verified_data(folder, key, cfg)
        except CacheCheckError as e:                  # rendered again below, with a note
            damaged = None if isinstance(e, UncheckedFile) else str(e)
            for name in ("manifest.json", *(f"{s}.npz" for s in SPLITS)):
                discard(folder / name)
        else:
            log(f"poevp train-data: cached {folder} (sha256 {key[:12]}; rendered in "
                f"{data.manifest['timing']['render_seconds']:.0f} s)")
            return data
    t0, c0 = time.perf_counter(), time.process_time()
    base = load_scene(scene, [f"render.resolution={list(cfg.resolution)}"])
    if not base.render.roi_shape:
        raise SceneError(f"{base.toml_path}: render.roi_shape: training data needs a plate (roi_shape = \"plate\")")
    geo = calibrate(base)
    todo = draws(cfg)
    overrides = {(s, d.index): sequence_overrides(base, d, cfg, geo) for s in SPLITS for d in todo[s]}
    folder.mkdir(parents=True, exist_ok=True)
    remote = cluster is not None and not cluster.local
    if remote:
        results = _render_on_dask(scene, overrides, folder / "render", cluster, progress, log)
    else:
        from tqdm import tqdm

        results = {}
        for (s, i), ov in tqdm(overrides.items(), desc=f"render {Path(str(scene)).name} sequences",
                               disable=not progress or None):
            results[s, i] = render_frames(load_scene(scene, ov))
    render_s, render_cpu_s = time.perf_counter() - t0, time.process_time() - c0
    for s in SPLITS:
        frames = np.stack([results[s, d.index][0] for d in todo[s]])
        boxes = np.stack([results[s, d.index][1] for d in todo[s]])
        with atomic_path(folder / f"{s}.npz") as tmp:
            with open(tmp, "wb") as f:
                np.savez_compressed(f, frames=frames, boxes=boxes)
        write_checksum(folder / f"{s}.npz")
    texts = {s: sorted({d.text for d in todo[s]}) for s in SPLITS}
    manifest = {"scene": str(resolve_scene_path(scene).resolve()), "content_sha256": key, **parts,
                "geometry": asdict(geo),
                "split": {"how": "train / val / test: disjoint seed streams (SPLIT_SEEDS), plate texts "
                                 "starting with disjoint letters (SPLIT_LETTERS), trajectories drawn per seed",
                          "seed_offsets": SPLIT_SEEDS, "text_first_letters": SPLIT_LETTERS,
                          "sequences": dict(zip(SPLITS, cfg.sequences)), "texts": texts},
                "sequences": {s: [asdict(d) for d in todo[s]] for s in SPLITS},
                "timing": {"render_seconds": render_s, "render_cpu_seconds_client": render_cpu_s,
                           "where": "dask" if remote else "local",
                           "frames_rendered": sum(cfg.sequences) * cfg.frames}}
    write_json(folder / "manifest.json", manifest)       # last: its presence marks a complete set
    write_checksum(folder / "manifest.json")
    log(f"poevp train-data: {sum(cfg.sequences)} sequences x {cfg.frames} frames at "
        f"{cfg.resolution[0]}x{cfg.resolution[1]} rendered in {render_s:.0f} s -> {folder}")
    data = load_data(folder)
    data.rendered = True
    if damaged is not None:
        note_rebuilt(folder, damaged, kind="folder")
    return data


def _render_on_dask(scene, overrides: dict, out: Path, cl: ClusterSettings, progress: bool, log) -> dict:
    """Each sequence a point of the sweep machinery (apps/sweep/sweep.py `run_points`): job
    `train_sequence` (apps/train/train_render.py), scene bundle or shared paths, worker checks, retries."""
    from poevp_optics.apps.sweep.bundle import make_plan, scene_inputs, with_hashes
    from poevp_optics.apps.sweep.sweep import run_points
    from poevp_optics.scene.load import load_scene, resolve_scene_path

    hashes: dict[str, str] = {}
    todo, folders = [], {}
    for n, ((s, i), ov) in enumerate(overrides.items()):
        refs = tuple(with_hashes(scene_inputs(load_scene(scene, ov, cross_checks=False)), hashes))
        pkey = f"{s}-{i:05d}"
        folders[s, i] = out / "points" / f"{pkey}-s0"
        todo.append(({"point": n, "seed": 0, "point_key": pkey}, tuple(ov), refs, folders[s, i]))
    plan = make_plan("shared" if cl.shared_fs else "bundle", resolve_scene_path(scene),
                     [r for t in todo for r in t[2]])
    df = run_points(todo, out, JOB, plan, cl, progress=progress, log=log)
    failed = df[df["status"] != "ok"] if df is not None else None
    if failed is not None and len(failed):
        raise SceneError(f"{out}: {len(failed)} sequences failed on the cluster, first: {failed.iloc[0]['error']}")
    res = {}
    for k, f in folders.items():
        z = np.load(f / "frames.npz")
        res[k] = (z["frames"], z["boxes"])
    return res
