"""What a sweep point reads, and how it travels to a Dask worker on another machine and back.

A point reads files besides the code: the TOML, the XML and every file it names, spectrum
tables, photometric lamp files, sheeting tables, the measured PSF, predictor weights, a frame
source's frames, video and CSVs ([source], sources/kinds.py), and for a chart the reference
camera's scene. `scene_inputs` lists them, each as an `InputRef`: the key
that names it, the file the client reads, its SHA-256, and how a worker finds it:

| kind       | named                                   | on a worker                                 |
|------------|-----------------------------------------|---------------------------------------------|
| `scene`    | relative to the scene (TOML/XML folder) | the bundle's mirror of the scene tree       |
| `absolute` | by an absolute path                     | the same path: a shared file system, verified |
| `assets`   | relative, found in the package's assets/ | the worker's own assets/ when its bytes match; else the client's copy from the bundle, put where the lookup looks first (beside the XML or TOML), or its key pointed at the copy (spectrum tables, default weights) |

Two ways of giving a worker the files (`InputPlan.mode`):

* `bundle`: a zip of the `scene` files (at their paths under the bundle root, the common
  folder of the scene and everything it names relatively, so `../shared/x.png` still resolves)
  and of the `assets` files, built once per sweep by the client and scattered to the workers.
  A point unpacks what it reads into its own temporary folder, checking every SHA-256.
* `shared`: the worker reads the client's paths (a shared file system, or a LocalCluster on
  this machine); every file is hashed on the worker and must match.

Either way a worker whose files differ from the client's stops the sweep (`InputMismatch`, one
line naming the key, the path and both hashes), and after loading the scene the worker lists
its inputs again and compares them with the client's list, so no lookup can quietly resolve to
another file there. Paths of the temporary folder in a point's report and error messages are
mapped back to the client's paths (`map_paths`).

A point's outputs come back as a zip of its folder (`pack_folder`), unpacked by the client
(`unpack_archive`), which refuses absolute names, `..` and links.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import shutil
import socket
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Iterator

from poevp_optics.core.exceptions import UserError

#: Prefix of a point's temporary folder on a worker: poevp-point-<host>-<pid>-XXXX.
WORKDIR_PREFIX = "poevp-point-"
#: Suffixes already compressed: stored, not deflated, in an archive.
_STORED = (".png", ".exr", ".npz", ".parquet", ".safetensors", ".jpg", ".zip", ".gz")


class InputMismatch(UserError):
    """A worker does not see the bytes the client read (or cannot be given them)."""


@dataclass(frozen=True)
class InputRef:
    """One file a point reads.

    key: what names it (`spectra.lamp.source`, `scene.xml: <texture id='t'> filename`, ...).
    source: the file the client read (absolute, symlinks resolved). sha256: its content hash.
    kind: `scene`, `absolute` or `assets` (module docstring).
    place: where a worker looks for it as the client spells it (absolute, not resolved): the
      file itself for `scene` and `absolute`; for `assets` the candidate looked at before the
      package's assets/ (beside the XML or TOML), or "" when assets/ is the only place.
    asset: its path under the package's assets/ (`assets` only).
    override: for `assets` with no earlier candidate: `KEY=TEMPLATE` that points the scene at
      a copy (`spectra.lamp.source=file:{}`), or "" when none can.
    """

    key: str
    source: str
    kind: str
    place: str = ""
    asset: str = ""
    override: str = ""
    sha256: str = ""


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 of a file's bytes (hex)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _lexical(path: Path) -> Path:
    """Absolute and normalised (`..` folded) without resolving links: how the path is spelt."""
    return Path(os.path.normpath(os.path.abspath(path)))


# ---------------------------------------------------------------------------- inputs of a scene
class _Finder:
    """Resolves the names in one scene the way the loaders do (scene/validate.py,
    apps/run/preflight.py, core/spectra.py, camera/relay.py, render/materials/) and records each
    file as an InputRef."""

    def __init__(self, prefix: str = "", may_override: bool = True):
        from poevp_optics.core.paths import ASSETS_DIR

        self.assets_dir = ASSETS_DIR
        self.prefix = prefix
        self.may_override = may_override
        self.refs: list[InputRef] = []

    def add(self, key: str, value: str, bases: list[Path], *, assets: bool, override: str = "",
            lookup_bases: list[Path] | None = None) -> None:
        """`value` as named under `key`: absolute, else under `bases` in order (as the client
        spells them; `lookup_bases` where they really are, when that differs), else assets/."""
        if not value:
            return
        key = self.prefix + key
        p = Path(value)
        if p.is_absolute():
            if p.is_file():
                self.refs.append(InputRef(key, str(p.resolve()), "absolute", place=str(_lexical(p))))
            return
        for spelt, real in zip(bases, lookup_bases or bases):
            if (real / p).is_file():
                self.refs.append(InputRef(key, str((real / p).resolve()), "scene",
                                          place=str(_lexical(spelt / p))))
                return
        if assets and (self.assets_dir / p).is_file():
            first = str(_lexical(bases[0] / p)) if bases else ""
            self.refs.append(InputRef(key, str((self.assets_dir / p).resolve()), "assets", place=first,
                                      asset=p.as_posix(),
                                      override=override if (not first and self.may_override) else ""))


def _xml_names(xml_real: Path, rel: Path, seen: set) -> Iterator[tuple[str, str, Path, dict]]:
    """(what, value, folder, defaults) for every file an XML names (`<string name="filename">`,
    `filename=` attributes of `<spectrum>` and `<include>`), following includes; `folder` is
    the naming file's folder relative to the main XML's, `what` names the element."""
    if xml_real in seen:
        return
    seen.add(xml_real)
    try:
        root = ET.parse(xml_real).getroot()
    except (ET.ParseError, OSError):
        return                                   # load_scene / preflight report it
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    for parent in root.iter():
        if parent.get("filename"):
            yield f"<{parent.tag}> filename", parent.get("filename"), rel, defaults
            if parent.tag == "include" and not Path(parent.get("filename")).is_absolute():
                inc = Path(parent.get("filename"))
                yield from _xml_names((xml_real.parent / inc).resolve(), rel / inc.parent, seen)
        for child in parent:
            if child.tag == "string" and child.get("name") == "filename":
                what = f"<{parent.tag} type={parent.get('type')!r}" + \
                       (f" id={parent.get('id')!r}" if parent.get("id") else "") + "> filename"
                yield what, child.get("value") or "", rel, defaults


def _xml_inputs(f: _Finder, spec, toml_dir: Path, toml_real: Path) -> None:
    """The XML (`render.xml`) and every file it names, as Mitsuba and preflight resolve them."""
    f.add("render.xml", spec.render.xml, [toml_dir], lookup_bases=[toml_real], assets=False)
    # the XML as a worker sees it (no links in a mirror) and as the client reads it
    xml_spelt = Path(f.refs[-1].place).parent if f.refs[-1].key.endswith("render.xml") else spec.xml_path.parent
    xml_real = spec.xml_path.parent
    # $parameters the TOML binds (lamp files, sheeting, a generated plate) are the TOML's
    # inputs; the others take the XML's <default>
    bound = {f"{n}_distribution" for n, s in spec.spectra.items() if s.distribution} | set(spec.sheeting)
    if spec.plate.text:
        bound.add(spec.plate.param)
    for what, value, rel, defaults in _xml_names(spec.xml_path, Path("."), set()):
        if value.startswith("$"):
            if value[1:] in bound:
                continue
            what, value = f"{what} (${value[1:]})", defaults.get(value[1:], "")
        spelt, real = [xml_spelt / rel, xml_spelt], [xml_real / rel, xml_real]
        if rel == Path("."):
            spelt, real = spelt[:1], real[:1]
        f.add(f"{spec.xml_path.name}: {what}", value, spelt, lookup_bases=real, assets=True)


def _source_inputs(f: _Finder, spec, toml_dir: Path, toml_real: Path) -> None:
    """A frame source's files (sources/kinds.py `SOURCES`: the keys its kind takes): the frames
    its glob matches (sorted, as frames.frame_files), the video, times and boxes CSVs, named
    relative to the scene's folder or absolute; its spectrum table (file:, as spectra tables)."""
    from poevp_optics.sources.frames import frame_files
    from poevp_optics.sources.kinds import SOURCES

    src, keys = spec.source, SOURCES[spec.source.kind].keys
    if "frames" in keys and src.frames:
        absolute = Path(src.frames).expanduser().is_absolute()
        for i, p in enumerate(frame_files(Path(spec.toml_path).parent, src.frames)):
            name = str(p) if absolute else os.path.relpath(p, Path(spec.toml_path).parent)
            f.add(f"source.frames[{i}]", name, [toml_dir], lookup_bases=[toml_real], assets=False)
    for key in ("video", "times_csv", "boxes"):
        if key in keys and getattr(src, key):
            f.add(f"source.{key}", str(Path(getattr(src, key)).expanduser()), [toml_dir],
                  lookup_bases=[toml_real], assets=False)
    if "spectrum" in keys and src.spectrum.startswith("file:"):
        f.add("source.spectrum", src.spectrum[5:], [], assets=True, override="source.spectrum=file:{}")


def scene_inputs(spec, *, _prefix: str = "", _may_override: bool = True) -> list[InputRef]:
    """Every file a run of `spec` reads besides the code, without hashes (`with_hashes`)."""
    from poevp_optics.core.paths import shipped_weights
    from poevp_optics.control.predictors import PREDICTORS
    from poevp_optics.scene.load import load_scene
    from poevp_optics.camera.sensor import SENSOR_PRESETS

    f = _Finder(_prefix, _may_override)
    toml = _lexical(spec.toml_path)
    toml_dir, toml_real = toml.parent, Path(spec.toml_path).resolve().parent
    f.refs.append(InputRef(f.prefix + "scene file", str(Path(spec.toml_path).resolve()), "scene",
                           place=str(toml)))
    if spec.xml_path is not None:
        _xml_inputs(f, spec, toml_dir, toml_real)
    _source_inputs(f, spec, toml_dir, toml_real)
    # spectrum tables: file:<absolute> or under assets/ only (spectra.load_spectrum)
    raw_spectra = spec.raw.get("spectra", {})
    for name, s in spec.spectra.items():
        key = f"spectra.{name}.source" if name in raw_spectra else "chart.source"
        if isinstance(s.source, str) and s.source.startswith("file:"):
            f.add(key, s.source[5:], [], assets=True, override=f"{key}=file:{{}}")
        if s.distribution and s.distribution.startswith("file:"):
            f.add(f"spectra.{name}.distribution", s.distribution[5:], [toml_dir], lookup_bases=[toml_real],
                  assets=True)
    qe = spec.sensor.qe or SENSOR_PRESETS[spec.sensor.preset].qe
    if isinstance(qe, str) and qe.startswith("file:"):
        f.add("sensor.qe", qe[5:], [], assets=True, override="sensor.qe=file:{}")
    for name, sh in spec.sheeting.items():
        if sh.source.startswith("file:"):
            f.add(f"sheeting.{name}.source", sh.source[5:], [toml_dir], lookup_bases=[toml_real], assets=True)
    if spec.relay.psf == "measured" and spec.relay.measured_file:
        f.add("relay.measured_file", spec.relay.measured_file, [toml_dir], lookup_bases=[toml_real], assets=True)
    if spec.dmd.enabled and PREDICTORS[spec.predictor.name].takes_weights:
        given = spec.raw.get("predictor", {}).get("weights", "")
        if given:
            f.add("predictor.weights", str(Path(given).expanduser()), [toml_dir], lookup_bases=[toml_real],
                  assets=False)
        else:
            w = shipped_weights(spec.predictor.name)
            # `dmvfn` falls back to the lite weights when the full ones are not shipped; the
            # fallback cannot be pointed at a copy (control/predictors/dmvfn.py), so it is only verified
            shipped = w if w.exists() or spec.predictor.name != "dmvfn" else shipped_weights("dmvfn_lite")
            f.add("predictor.weights", str(shipped.resolve().relative_to(f.assets_dir.resolve())), [],
                  assets=True, override="predictor.weights={}" if w.exists() else "")
    if spec.chart.reference_camera:
        ref = toml_dir / spec.chart.reference_camera
        ref_toml = ref / "scene.toml" if (toml_real / spec.chart.reference_camera).is_dir() else ref
        f.refs += scene_inputs(load_scene(ref_toml, cross_checks=False),
                               _prefix=f"{f.prefix}chart.reference_camera: ", _may_override=False)
    return f.refs


def with_hashes(refs: list[InputRef], cache: dict[str, str] | None = None) -> list[InputRef]:
    """`refs` with their SHA-256 (each file read once per `cache`)."""
    cache = {} if cache is None else cache
    out = []
    for r in refs:
        if r.source not in cache:
            cache[r.source] = file_sha256(r.source)
        out.append(replace(r, sha256=cache[r.source]))
    return out


# ---------------------------------------------------------------------------- the plan a point carries
@dataclass(frozen=True)
class InputPlan:
    """How every point of a sweep finds its inputs (sent with each task; small).

    mode: `bundle` or `shared`. root: the bundle root as the client spells it (the common
    folder of every `scene` file). scene: the client's TOML path (absolute, as spelt).
    assets_dir: the client's package assets/. bundle_sha256: of the bundle's bytes."""

    mode: str
    root: str
    scene: str
    assets_dir: str
    bundle_sha256: str = ""


@dataclass(frozen=True)
class Bundle:
    """A sweep's scene bundle: zip bytes (`scene/<path under root>`, `assets/<path>`)."""

    data: bytes
    sha256: str
    files: int


def make_plan(mode: str, scene_toml: str | os.PathLike, refs: list[InputRef]) -> InputPlan:
    """The plan for `refs` (every point's refs together): the bundle root is the common folder
    of the scene and of every place a `scene` file (or a placed asset) is looked for."""
    from poevp_optics.core.paths import ASSETS_DIR

    if mode not in ("bundle", "shared"):
        raise ValueError(f"unknown input mode {mode!r}")
    toml = _lexical(Path(scene_toml))
    places = [str(toml.parent)] + [r.place for r in refs if r.kind == "scene" or (r.kind == "assets" and r.place)]
    root = os.path.commonpath(places)
    return InputPlan(mode, root, str(toml), str(ASSETS_DIR.resolve()))


def make_bundle(plan: InputPlan, refs: list[InputRef]) -> Bundle:
    """Zip the `scene` files at their paths under the root and the `assets` files (hashed refs)."""
    buf = io.BytesIO()
    names = set()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for r in refs:
            if r.kind == "scene":
                name = "scene/" + Path(os.path.relpath(r.place, plan.root)).as_posix()
            elif r.kind == "assets":
                name = "assets/" + r.asset
            else:
                continue
            if name in names:
                continue
            names.add(name)
            data = Path(r.source).read_bytes()
            if hashlib.sha256(data).hexdigest() != r.sha256:
                raise InputMismatch(f"{r.source} ({r.key}): changed while the sweep was being prepared")
            zf.writestr(_zipinfo(name), data, compress_type=_compression(name))
    data = buf.getvalue()
    return Bundle(data, hashlib.sha256(data).hexdigest(), len(names))


def _zipinfo(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))   # bytes depend on content only
    info.external_attr = 0o644 << 16
    return info


def _compression(name: str) -> int:
    return zipfile.ZIP_STORED if name.lower().endswith(_STORED) else zipfile.ZIP_DEFLATED


# ---------------------------------------------------------------------------- on the worker
@dataclass(frozen=True)
class Materialized:
    """Where a point finds its inputs on this worker.

    scene: the TOML to load. overrides: extra `KEY=VALUE` pointing assets-only keys at copies.
    path_map: (worker prefix, client prefix) pairs for `map_paths`."""

    scene: str
    overrides: tuple[str, ...] = ()
    path_map: tuple[tuple[str, str], ...] = field(default_factory=tuple)


def pid_alive(pid: int) -> bool:
    """Whether process `pid` runs (a zombie, killed but not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:                     # another user's process
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


@contextlib.contextmanager
def point_workdir() -> Iterator[Path]:
    """A temporary folder for one point, removed afterwards however the point ends. Folders
    that killed workers of this host left (their process is gone) are removed first."""
    tmp = Path(tempfile.gettempdir())
    host = socket.gethostname().replace("-", "_")
    for old in tmp.glob(f"{WORKDIR_PREFIX}{host}-*"):
        try:
            pid = int(old.name[len(WORKDIR_PREFIX) + len(host) + 1:].split("-", 1)[0])
        except ValueError:
            continue
        if pid != os.getpid() and not pid_alive(pid):
            shutil.rmtree(old, ignore_errors=True)
    work = Path(tempfile.mkdtemp(prefix=f"{WORKDIR_PREFIX}{host}-{os.getpid()}-")).resolve()
    try:
        yield work
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _check_file(path: str | os.PathLike, ref: InputRef, hint: str) -> None:
    p = Path(path)
    if not p.is_file():
        raise InputMismatch(f"{ref.key}: {p} is missing there (the client read {ref.source}); {hint}")
    got = file_sha256(p)
    if got != ref.sha256:
        raise InputMismatch(f"{ref.key}: {p} holds other bytes there (sha256 {got[:12]}, the client's "
                            f"{ref.sha256[:12]}); {hint}")


def materialize(plan: InputPlan, refs: list[InputRef], bundle: bytes | None, work: Path,
                assets_dir: Path | None = None) -> Materialized:
    """Give this worker the point's inputs under `work` (module docstring); raise InputMismatch.

    assets_dir: this worker's package assets/ (default: the installed package's)."""
    from poevp_optics.core.paths import ASSETS_DIR

    assets_dir = Path(assets_dir or ASSETS_DIR).resolve()
    shared_hint = ("the workers must see the client's files at the same paths with --shared-fs "
                   "(leave it out to send the scene with the sweep)")
    abs_hint = ("name the file relative to the scene so it travels with the sweep, or keep it on a "
                "file system the workers share")
    if plan.mode == "shared":
        for r in refs:
            if r.kind == "assets":
                _check_file(assets_dir / r.asset, r, "install the same poevp_optics (and assets/) on the "
                            "workers, or leave out --shared-fs to send the files with the sweep")
            else:
                _check_file(r.place, r, shared_hint if r.kind == "scene" else abs_hint)
        pm = ((str(assets_dir), plan.assets_dir),) if str(assets_dir) != plan.assets_dir else ()
        return Materialized(plan.scene, (), pm)
    if bundle is None:
        raise InputMismatch("no scene bundle reached this worker")
    mirror = work / (Path(plan.root).name or "root")
    copies = work / "assets"
    overrides: list[str] = []
    with zipfile.ZipFile(io.BytesIO(bundle)) as zf:
        def put(name: str, dest: Path, ref: InputRef) -> None:
            data = zf.read(name)
            if hashlib.sha256(data).hexdigest() != ref.sha256:
                raise InputMismatch(f"{ref.key}: the bundle's {name} does not match its hash")
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)

        for r in refs:
            if r.kind == "scene":
                dest = mirror / os.path.relpath(r.place, plan.root)
                if not dest.is_file():
                    put("scene/" + Path(os.path.relpath(r.place, plan.root)).as_posix(), dest, r)
            elif r.kind == "absolute":
                _check_file(r.place, r, abs_hint)
            else:
                own = assets_dir / r.asset
                if own.is_file() and file_sha256(own) == r.sha256:
                    continue                        # the worker's package holds the same bytes
                if r.place:
                    put("assets/" + r.asset, mirror / os.path.relpath(r.place, plan.root), r)
                elif r.override:
                    dest = copies / r.asset
                    put("assets/" + r.asset, dest, r)
                    key, template = r.override.split("=", 1)
                    overrides.append(f"{key}={json.dumps(template.format(dest))}")   # a TOML string
                else:
                    _check_file(own, r, "install the same poevp_optics assets/ on the workers")
    pm = [(str(mirror), plan.root), (str(copies), plan.assets_dir)]
    if str(assets_dir) != plan.assets_dir:
        pm.append((str(assets_dir), plan.assets_dir))
    return Materialized(str(mirror / os.path.relpath(plan.scene, plan.root)), tuple(overrides), tuple(pm))


def check_same_inputs(expected: list[InputRef], spec, path_map) -> None:
    """After loading: the scene on this worker reads the same bytes under the same keys as on
    the client (a lookup that resolved elsewhere here is caught). Raises InputMismatch."""
    want = {r.key: r for r in expected}
    got = {r.key: r for r in with_hashes(scene_inputs(spec))}
    for key in sorted(set(want) | set(got)):
        w, g = want.get(key), got.get(key)
        if w is None:
            raise InputMismatch(f"{key}: reads {map_paths(g.source, path_map)} here, which the client "
                                "did not read")
        if g is None:
            raise InputMismatch(f"{key}: the client read {w.source}, this worker finds nothing")
        if g.sha256 != w.sha256:
            raise InputMismatch(f"{key}: reads {map_paths(g.source, path_map)} here (sha256 "
                                f"{g.sha256[:12]}), the client {w.source} ({w.sha256[:12]})")


def map_paths(obj, path_map):
    """`obj` (str, or dicts/lists of them) with worker prefixes replaced by the client's."""
    if isinstance(obj, str):
        for worker, client in path_map:
            if worker != client:
                obj = obj.replace(worker, client)
        return obj
    if isinstance(obj, dict):
        return {k: map_paths(v, path_map) for k, v in obj.items()}
    if isinstance(obj, list):
        return [map_paths(v, path_map) for v in obj]
    return obj


# ---------------------------------------------------------------------------- outputs back
def pack_folder(folder: Path) -> bytes:
    """Zip of every regular file under `folder` (names relative to it)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=6) as zf:
        for p in sorted(folder.rglob("*")):
            if p.is_file() and not p.is_symlink():
                name = p.relative_to(folder).as_posix()
                zf.writestr(_zipinfo(name), p.read_bytes(), compress_type=_compression(name))
    return buf.getvalue()


def unpack_archive(data: bytes, dest: Path, *, skip: tuple[str, ...] = ()) -> int:
    """Write the files of a `pack_folder` archive under `dest`; returns how many. Names that are
    absolute, climb out (`..`) or are links are refused (ValueError); `skip` names are left out."""
    n = 0
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        for info in zf.infolist():
            name = info.filename
            parts = Path(name).parts
            if name.startswith("/") or ".." in parts or not parts or (info.external_attr >> 16) & 0o170000 == 0o120000:
                raise ValueError(f"archive member {name!r}: not a plain relative file name")
            if info.is_dir() or name in skip:
                continue
            target = dest.joinpath(*parts)
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_bytes(zf.read(info))
            n += 1
    return n
