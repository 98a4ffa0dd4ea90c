"""A run's rendered exposures stored on disk and replayed: radiance rendered once for every run
whose render inputs are the same (`poevp sweep` and `poevp search` points that differ only in
what comes after the render: objective, DMD, mask law and controller, loop, predictor,
attenuator, relay, sensor).

Key. A render is named `<group>-g<guard_px>`: `group` is `render_group(scene, refs)`, a SHA-256
of the resolved `RenderScene` (render/render_scene.py) without the text of the overrides that
made it and without the camera-only numerical settings (`CAMERA_ONLY_ACCURACY`), with the
exposure window, radiance-node times and weights of every frame in place of the timing
parameters that produce them (so a DMD or timing key that moves no node keeps the render), the
SHA-256 of every file the render reads (the XML and what it names, spectrum tables, lamp and
sheeting files, QE table: a sweep's input list without the camera's files), the software
versions, the plate font's SHA-256 and the code of render/, sources/ and core/ (`code_digest`:
its syntax, so an edit to comments alone keeps the renders); `guard_px` is the camera's guard
band (camera.Camera.guard_px: the relay PSF and the objective set it), known only once the
camera is built, so the run adds it.

Store. One folder per key: `frame_NNNN.npz` per frame (every array of the `RenderedExposure`
with its dtype, and its scalars with their Python or NumPy type), `temporal.npz` (the renders
of the temporal-error estimate, apps/run/temporal_check.py, by time, seed and spp) and
`manifest.json` (the renderer's path, variant, counters and light weights; written last), each
with its checksum file (core/cache.py). A recording is written into a staging folder beside
the store and renamed into place whole when the run succeeded, so a killed run leaves no
partial render under a key. On open every file of a stored render is checked against its
checksum; a damaged one is noted on stderr and the render is made again (core/cache.py's
rule). A replayed run reads the same arrays the recorded run read, so its outputs are
bit-identical to rendering again (tests/regression/test_sweep_reuse.py).

Only Mitsuba renders are stored: a frame source ([source] kind other than `mitsuba`) reads
its frames again, which costs about what reading a stored render costs.

Disk: per frame about (2 K + 2) x mirrors x 8 bytes (K radiance nodes and their variances,
the mean and its variance), e.g. 21 frames at 1080x1920 with K = 5: ~4 GB per key.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import json
import os
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np

from poevp_optics.core.cache import CacheCheckError, checksum_problem, load_verified, note_rebuilt, save_verified
from poevp_optics.core.frame import Frame, Quantity, RenderedExposure

#: Version of the stored format and of the key recipe: bump on any change to either.
FORMAT = 1
#: Accuracy fields only the camera reads (core/accuracy.py; render/ and sources/ never read
#: them: tests/unit/test_render_cache.py checks): left out of the key.
CAMERA_ONLY_ACCURACY = ("psf_support_energy", "psf_support_px", "guard_max_px", "poisson_sampler",
                        "objective_field_samples", "objective_band_samples", "objective_pupil_rays",
                        "objective_support_energy", "objective_guard_max_px", "registration_oversample",
                        "dmd_full_table_max")
#: Input-list keys (apps/sweep/bundle.py scene_inputs) of files only the camera or loop reads.
CAMERA_ONLY_INPUTS = ("predictor.weights", "relay.measured_file")
#: Packages whose code shapes a render beyond what its resolved RenderScene says: the renderer,
#: its plugins and materials (render/), the generated plate and sign textures, meshes and maps
#: (sources/), and the spectra, seeds and units they use (core/).
RENDER_CODE = ("render", "sources", "core")
#: The package folder (poevp_optics/), the root `code_digest`'s parts are named from.
PACKAGE_DIR = Path(__file__).resolve().parents[1]
MANIFEST = "manifest.json"
TEMPORAL = "temporal.npz"


# ---------------------------------------------------------------------------- the key
def _canonical(obj):
    """A JSON-able, process-independent form of the render's inputs (dataclasses, mappings,
    paths, enums, arrays; floats exactly, as JSON writes their shortest repr)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {"__type__": type(obj).__name__,
                **{f.name: _canonical(getattr(obj, f.name)) for f in dataclasses.fields(obj)}}
    if isinstance(obj, (Mapping, MappingProxyType)):
        return {str(k): _canonical(obj[k]) for k in sorted(obj, key=str)}
    if isinstance(obj, (list, tuple)):
        return [_canonical(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return {"dtype": str(obj.dtype), "shape": list(obj.shape),
                "sha256": hashlib.sha256(np.ascontiguousarray(obj).tobytes()).hexdigest()}
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, enum.Enum):
        return f"{type(obj).__name__}.{obj.name}"
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if obj is None or isinstance(obj, (bool, int, float, str)):
        return obj
    raise TypeError(f"render key: cannot name a {type(obj).__name__} by its content")


def render_inputs(scene, input_hashes: Mapping[str, str] = MappingProxyType({})) -> dict:
    """What the render of `scene` (a RenderScene) depends on, as a JSON-able dict (module
    docstring); `input_hashes`: {input key: SHA-256} of the files the run reads."""
    from poevp_optics.core.version import __version__

    fields = {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene)
              if f.name not in ("origin", "timing", "clock")}
    fields["accuracy"] = {k: v for k, v in _canonical(scene.accuracy).items() if k not in CAMERA_ONLY_ACCURACY}
    frames = [{"window_s": list(scene.exposure_window_s(i)), "start_s": scene.frame_start_s(i),
               "nodes_s": [float(t) for t in scene.subframe_times_s(i)],
               "weights": [float(w) for w in scene.subframe_weights(i)]} for i in range(scene.timing.frames)]
    files = {k: v for k, v in sorted(input_hashes.items())
             if not any(k == c or k.startswith(c + " ") for c in CAMERA_ONLY_INPUTS)}
    return {"format": FORMAT, "scene": _canonical(fields), "frames": frames, "files": files,
            "software": {"poevp_optics": __version__, **_render_versions()}}


def _render_versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("mitsuba", "drjit", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = None
    return out


def render_group(scene, input_hashes: Mapping[str, str] = MappingProxyType({})) -> str:
    """The first part of a render's key (module docstring): 20 hex characters, over
    `render_inputs`, the plate font's SHA-256 (the plate and sign textures are drawn with it)
    and the code of RENDER_CODE (`code_digest`), so that a stored render does not outlive an
    edit to the renderer, the textures or the font."""
    key = {**render_inputs(scene, input_hashes), **render_code_inputs()}
    text = json.dumps(key, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def render_code_inputs() -> dict:
    """What shapes a render beyond its resolved scene and files, for every render-cache key (the
    sweep's stored renders here, evaluate's sequences): the plate font's SHA-256 (the plate and
    sign textures are drawn with it) and the code of RENDER_CODE (`code_digest`)."""
    from poevp_optics.sources.plates import plate_font_sha256

    return {"plate_font_sha256": plate_font_sha256(), "code": code_digest()}


def _code_text(path: Path) -> bytes:
    """A source file's code without its comments, docstrings and layout (its syntax tree), so
    that an edit to the documentation alone keeps the caches; the raw bytes when it does not parse."""
    import ast

    raw = path.read_bytes()
    try:
        tree = ast.parse(raw)
    except SyntaxError:
        return raw
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(body, list) and body and isinstance(body[0], ast.Expr)
                and isinstance(body[0].value, ast.Constant) and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree, include_attributes=False).encode()


@functools.lru_cache(maxsize=16)
def code_digest(parts: tuple[str, ...] = RENDER_CODE, root: Path = PACKAGE_DIR) -> str:
    """SHA-256 (16 hex) of the package's code: for each of `parts` (a folder under `root`, or one
    file), every *.py file's path relative to `root` and its code (`_code_text`), in sorted
    order; any edit to that code changes it, an edit to comments or docstrings does not."""
    h = hashlib.sha256()
    for part in parts:
        where = Path(root) / part
        for p in ([where] if where.is_file() else sorted(where.rglob("*.py"))):
            h.update(p.relative_to(root).as_posix().encode() + b"\0")
            h.update(_code_text(p) + b"\0")
    return h.hexdigest()[:16]


def render_key(group: str, guard_px: int) -> str:
    """A stored render's folder name: its group and the camera's guard band (px)."""
    return f"{group}-g{int(guard_px)}"


# ---------------------------------------------------------------------------- typed scalars
def _enc(v):
    """A scalar (or a tuple/list/dict of them) with its type, for JSON."""
    if v is None:
        return {"t": "none"}
    if isinstance(v, np.generic):
        return {"t": "np", "dtype": str(v.dtype), "v": v.item()}
    if isinstance(v, enum.Enum):
        return {"t": "quantity", "v": v.name}
    if isinstance(v, (bool, int, float, str)):
        return {"t": type(v).__name__, "v": v}
    if isinstance(v, (tuple, list)):
        return {"t": type(v).__name__, "v": [_enc(x) for x in v]}
    if isinstance(v, dict):
        return {"t": "dict", "v": {str(k): _enc(x) for k, x in v.items()}}
    raise TypeError(f"stored render: cannot store a {type(v).__name__}")


def _dec(d):
    t, v = d["t"], d.get("v")
    if t == "none":
        return None
    if t == "np":
        return np.dtype(d["dtype"]).type(v)
    if t == "quantity":
        return Quantity[v]
    if t in ("bool", "int", "float", "str"):
        return {"bool": bool, "int": int, "float": float, "str": str}[t](v)
    if t in ("tuple", "list"):
        seq = [_dec(x) for x in v]
        return tuple(seq) if t == "tuple" else seq
    if t == "dict":
        return {k: _dec(x) for k, x in v.items()}
    raise ValueError(f"unknown stored type {t!r}")


# ---------------------------------------------------------------------------- one exposure on disk
_SCALARS = ("index", "t_start_s", "exposure_s", "roi", "rel_error", "rel_error_roi", "basis", "ground_truth",
            "spp", "target_met")


def save_exposure(tmp: Path, ex: RenderedExposure) -> None:
    """Every array of `ex` (dtype kept) and its scalars with their types, as one .npz."""
    fr = ex.radiance
    meta = {k: _enc(getattr(ex, k)) for k in _SCALARS}
    if ex.plates:                       # several plates' ROIs (render.roi_shape = "plates")
        meta["plates"] = _enc(ex.plates)
    meta["frame"] = {k: _enc(getattr(fr, k)) for k in ("quantity", "unit", "t_start_s", "exposure_s", "index")}
    arrays = {"subframe_times_s": np.asarray(ex.subframe_times_s), "radiance": np.asarray(fr.data),
              "variance": np.asarray(ex.variance), "meta": np.array(json.dumps(meta))}
    arrays.update({f"sub_{k:03d}": np.asarray(s) for k, s in enumerate(ex.subframes)})
    arrays.update({f"subvar_{k:03d}": np.asarray(s) for k, s in enumerate(ex.subframe_variances)})
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def load_exposure(path: Path) -> RenderedExposure:
    """The exposure `save_exposure` wrote (the same arrays and scalar types)."""
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        subs = tuple(z[n] for n in sorted(n for n in z.files if n.startswith("sub_")))
        subvars = tuple(z[n] for n in sorted(n for n in z.files if n.startswith("subvar_")))
        times, radiance, variance = z["subframe_times_s"], z["radiance"], z["variance"]
    s = {k: _dec(v) for k, v in meta.items() if k != "frame"}
    f = {k: _dec(v) for k, v in meta["frame"].items()}
    frame = Frame(radiance, f["quantity"], f["unit"], f["t_start_s"], f["exposure_s"], f["index"])
    return RenderedExposure(s["index"], s["t_start_s"], s["exposure_s"], times, subs, frame, variance, s["roi"],
                            s["rel_error"], s["rel_error_roi"], basis=s["basis"], subframe_variances=subvars,
                            ground_truth=s["ground_truth"], spp=s["spp"], target_met=s["target_met"],
                            plates=s.get("plates", ()))


def check_exposure(ex: RenderedExposure, index: int, shape: tuple) -> str | None:
    """Why a loaded exposure is not frame `index` of a render on the mirror grid `shape`."""
    if ex.index != index:
        return f"holds frame {ex.index}, not {index}"
    arrays = [ex.radiance.data, ex.variance, *ex.subframes, *ex.subframe_variances]
    if any(np.asarray(a).shape != tuple(shape) for a in arrays):
        return f"an image is not {shape[0]}x{shape[1]}"
    if not ex.basis and len(ex.subframes) != len(ex.subframe_times_s):
        return f"{len(ex.subframes)} radiance samples for {len(ex.subframe_times_s)} times"
    if not all(np.all(np.isfinite(a)) for a in arrays):
        return "an image holds a value that is not finite"
    if np.any(ex.variance < 0):
        return "a negative variance"
    return None


# ---------------------------------------------------------------------------- a stored render
def verify(folder: Path) -> tuple[dict | None, str | None]:
    """(manifest, None) when `folder` holds a complete stored render whose every file passes its
    checksum, else (None, why). A folder with no manifest is (None, "missing")."""
    path = folder / MANIFEST
    if not path.is_file():
        return None, "missing"
    try:
        man = load_verified(path, lambda p: json.loads(p.read_text()),
                            lambda m: None if isinstance(m, dict) and m.get("format") == FORMAT
                            and isinstance(m.get("files"), list) else f"not a format-{FORMAT} manifest")
    except CacheCheckError as e:
        return None, f"{MANIFEST}: {e}"
    for name in man["files"]:
        problem = checksum_problem(folder / name)
        if problem:
            return None, f"{name}: {problem}"
    return man, None


@dataclass(frozen=True)
class RecordedPlan:
    """What a run reads of the renderer's spectral plan (render/renderer.py SpectralPlan)."""

    mode: str
    reason: str
    notes: tuple[str, ...]


class Replay:
    """A stored render, read back in the order it was rendered: the renderer interface a run
    reads (render/radiance.py): guard_px, plan, variant, stats (the recorded render's counters),
    light_weights, temporal_skip, exposures(progress), set_time, render_once (the recorded
    temporal-error renders; any other is rendered live)."""

    temporal_skip = None

    def __init__(self, folder: Path, manifest: dict, scene, guard_px: int):
        from poevp_optics.render.renderer import RenderStats

        self.folder, self.manifest, self.scene, self.guard_px = folder, manifest, scene, int(guard_px)
        p = manifest["plan"]
        self.plan = RecordedPlan(p["mode"], p["reason"], tuple(p["notes"]))
        self.variant, self.variant_reason = manifest["variant"], manifest["variant_reason"]
        self.stats = RenderStats(**manifest["stats"])
        self.light_weights = manifest["light_weights"]
        self._time = None
        self._temporal = None
        self._live = None

    def _live_source(self):
        if self._live is None:
            from poevp_optics.render.radiance import MitsubaSource

            self._live = MitsubaSource(self.scene, guard_px=self.guard_px)
        return self._live

    def exposures(self, progress: bool = True):
        shape = tuple(self.manifest["shape"])
        for i in range(self.manifest["frames"]):
            path = self.folder / f"frame_{i:04d}.npz"
            try:
                yield load_verified(path, load_exposure, lambda ex, i=i: check_exposure(ex, i, shape))
            except CacheCheckError as e:       # damaged since it was opened: render the rest here
                print(f"poevp: stored render file {path} failed its check ({e}); rendering the run's "
                      "frames from here on again", file=sys.stderr, flush=True)
                live = self._live_source().exposures(progress)
                for ex in live:
                    if ex.index >= i:
                        yield ex
                return

    def set_time(self, t_s: float) -> None:
        self._time = float(t_s)
        if self._live is not None:
            self._live.set_time(t_s)

    def render_once(self, seed: int, spp: int) -> np.ndarray:
        if self._temporal is None:
            self._temporal = {}
            if TEMPORAL in self.manifest["files"]:
                with np.load(self.folder / TEMPORAL, allow_pickle=False) as z:
                    for j, (t, s, n) in enumerate(zip(z["t"], z["seed"], z["spp"])):
                        self._temporal[(float(t), int(s), int(n))] = z[f"img_{j:04d}"]
        img = self._temporal.get((self._time, int(seed), int(spp)))
        if img is not None:
            return img.copy()
        live = self._live_source()
        live.set_time(self._time)
        calls, secs = live.stats.calls, live.stats.seconds
        img = live.render_once(seed, spp)
        self.stats.calls += live.stats.calls - calls
        self.stats.seconds += live.stats.seconds - secs
        return img


class Recording:
    """A live source whose exposures and temporal-error renders are written into a staging
    folder as the run reads them; `commit` renames it into place. Everything else is the live
    source's."""

    def __init__(self, live, store: Path, key: str, label: str):
        self._live, self._store, self._key, self._label = live, Path(store), key, label
        self._store.mkdir(parents=True, exist_ok=True)
        self._stage = Path(tempfile.mkdtemp(prefix=f".{key}.staging-{os.getpid()}-", dir=self._store))
        self._files: list[str] = []
        self._shape = None
        self._frames = 0
        self._time = None
        self._renders: list[tuple[float, int, int, np.ndarray]] = []

    def __getattr__(self, name):
        return getattr(self._live, name)

    def exposures(self, progress: bool = True):
        for ex in self._live.exposures(progress):
            name = f"frame_{ex.index:04d}.npz"
            save_verified(self._stage / name, ex, save_exposure)
            self._files.append(name)
            self._shape = list(np.asarray(ex.radiance.data).shape)
            self._frames += 1
            yield ex

    def set_time(self, t_s: float) -> None:
        self._time = float(t_s)
        self._live.set_time(t_s)

    def render_once(self, seed: int, spp: int) -> np.ndarray:
        img = self._live.render_once(seed, spp)
        self._renders.append((self._time, int(seed), int(spp), np.array(img, copy=True)))
        return img

    def commit(self) -> Path | None:
        """Write the manifest and rename the staging folder into `<store>/<key>` (a complete
        render already there stays). Returns the folder, or None when the run read no frame."""
        if not self._frames:
            shutil.rmtree(self._stage, ignore_errors=True)
            return None
        if self._renders:
            arrays = {"t": np.array([r[0] for r in self._renders], np.float64),
                      "seed": np.array([r[1] for r in self._renders], np.int64),
                      "spp": np.array([r[2] for r in self._renders], np.int64),
                      **{f"img_{j:04d}": r[3] for j, r in enumerate(self._renders)}}
            save_verified(self._stage / TEMPORAL, arrays, lambda tmp, a: _savez(tmp, a))
            self._files.append(TEMPORAL)
        live, st = self._live, self._live.stats
        man = {"format": FORMAT, "key": self._key, "rendered_by": self._label, "frames": self._frames,
               "shape": self._shape, "files": self._files,
               "plan": {"mode": live.plan.mode, "reason": live.plan.reason, "notes": list(live.plan.notes)},
               "variant": live.variant, "variant_reason": live.variant_reason,
               "stats": {"calls": st.calls, "seconds": st.seconds, "samples_per_pixel": st.samples_per_pixel,
                         "variant": st.variant, "extra": json.loads(json.dumps(st.extra, default=str))},
               "light_weights": live.light_weights}
        save_verified(self._stage / MANIFEST, man, lambda tmp, m: Path(tmp).write_text(json.dumps(m, indent=1)))
        return install(self._stage, self._store / self._key)


def _savez(tmp, arrays: dict) -> None:
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)


def install(stage: Path, final: Path) -> Path:
    """Rename a complete render folder `stage` onto `final` unless a complete one is there
    already (then `stage` is removed); a damaged one there is replaced."""
    from poevp_optics.core.cache import build_lock

    with build_lock(final):
        if final.is_dir():
            if verify(final)[0] is not None:
                shutil.rmtree(stage, ignore_errors=True)
                return final
            shutil.rmtree(final, ignore_errors=True)
        os.replace(stage, final)
    return final


def clean_stale(store: Path) -> None:
    """Remove staging folders of recordings whose process is gone (a killed run's)."""
    if not store.is_dir():
        return
    for old in store.glob(".*.staging-*"):
        try:
            pid = int(old.name.split(".staging-", 1)[1].split("-", 1)[0])
        except (IndexError, ValueError):
            continue
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            shutil.rmtree(old, ignore_errors=True)
        except PermissionError:
            pass                                   # another user's process: alive


# ---------------------------------------------------------------------------- the hook a run calls
class RenderCache:
    """What a run asks of the stored renders (apps/run/render_run.py `run_frames`).

    group: `render_group` of the run's render inputs, computed by whoever asked (the sweep's
    client, which knows the files' hashes). read: folders holding stored renders (the sweep's
    `renders/`, or a worker's copy of the ones it was sent); store: where a render made here is
    recorded. label: who records (a sweep point's folder name). After the run, `outcome` says
    {"key", "reused", "rendered_by", "stored"} (stored: the folder a recording made, or None)."""

    def __init__(self, group: str, read: tuple[Path, ...], store: Path, label: str = ""):
        self.group, self.read, self.store, self.label = group, tuple(Path(p) for p in read), Path(store), label
        self.outcome: dict = {"key": None, "reused": False, "rendered_by": None, "stored": None,
                              "why": "not opened"}
        self._recording: Recording | None = None

    def open(self, scene, guard_px: int):
        """The run's source: a `Replay` of a stored render of this key, else a `Recording` of
        the live render; None for a scene whose radiance is not rendered (a frame source)."""
        if not scene.source.renders:
            self.outcome["why"] = f"radiance read from files ([source] kind = {scene.source.kind!r}), not rendered"
            return None
        key = render_key(self.group, guard_px)
        self.outcome.update(key=key, why="")
        for folder in self.read:
            man, why = verify(folder / key)
            if man is not None:
                self.outcome.update(reused=True, rendered_by=man.get("rendered_by"))
                return Replay(folder / key, man, scene, guard_px)
            if why != "missing":
                note_rebuilt(folder / key, why, kind="folder")
        from poevp_optics.render.radiance import MitsubaSource

        self._recording = Recording(MitsubaSource(scene, guard_px=guard_px), self.store, key, self.label)
        self.outcome["rendered_by"] = self.label
        return self._recording

    def report_section(self) -> dict:
        """The run report's `render_reuse` entry: the render's key, the same whether this run
        rendered it or replayed it (which one did is the sweep table's `render_reused`)."""
        o = self.outcome
        if o["key"] is None:
            return {"key": None, "why": o["why"]}
        return {"key": o["key"], "note": "the radiance of every run with this key is one render, stored "
                                         "under renders/<key> in the sweep folder; stages.render's calls "
                                         "and seconds are that render's"}

    def finish(self) -> None:
        """After the run (its temporal estimate included): a recording is stored."""
        if self._recording is not None:
            folder = self._recording.commit()
            self.outcome["stored"] = str(folder) if folder else None
            self._recording = None
