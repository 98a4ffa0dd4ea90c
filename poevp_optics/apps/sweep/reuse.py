"""Radiance rendered once per sweep: which points share a render, when each point may start, and
where the stored renders live (render/render_cache.py holds the key recipe and the store).

A point's *render group* is `render_group` of its resolved render inputs with the SHA-256 of the
files it reads (computed here on the client, where every point's files are hashed already); a
`render` job point of a Mitsuba scene has one, a chart point or a frame source's has none. The
first point of each group that has no stored render (the *leader*) runs first and records its
render; the group's other points are held back until it ends, then run and replay the stored
render (or record their own, when the camera's guard band, and so the render's key, differs).
A leader that fails releases its group: each point then renders for itself. The stored renders
live in the sweep's folder, `renders/<group>-g<guard_px>/` (several GB for a full-size run: 21
frames at 1080x1920 with K = 5 is ~4 GB), and travel by file, never whole in memory:

* Workers that share the client's file system (a LocalCluster, or --shared-fs) read them there
  (checksums verified on each read) and record a render there themselves: staged beside the
  store and renamed into place whole (render_cache.py's recording), so only its path comes back
  with the point's result; the client verifies it.
* Otherwise a worker records into a folder of its own, and the client pulls it file by file in
  chunks of CHUNK_BYTES (a small task on that worker per chunk), writes them into a staging
  folder, verifies and renames it into place, then asks the worker to remove its copy; a stored
  render goes to every worker the same way, pushed in chunks (a small task per chunk pinned to
  that worker) into the worker's inbox folder, verified there and renamed into place, once per
  render and worker; a worker that joins later renders for itself. Each of those small tasks
  checks that its worker is still in the cluster (a task pinned to a worker that left would wait
  for it for ever): a render whose worker left is given up (its group renders again), and a
  worker that left gets no push.

At most a chunk of a render is in the client's memory at a time.

The table's columns `render_key`, `render_reused` and `render_by` say which render each point
used, whether it replayed a stored one, and which point folder rendered it.
"""

from __future__ import annotations

from pathlib import Path

import os
import shutil
import tempfile

from poevp_optics.apps.sweep.cluster import worker_addresses
from poevp_optics.render.render_cache import clean_stale, install, render_group, verify

#: The results table's columns for reuse (module docstring).
REUSE_COLUMNS = ("render_key", "render_reused", "render_by")
#: Largest piece of a stored render in memory while it travels between client and worker (bytes).
CHUNK_BYTES = 64 << 20


def point_render_groups(scene, tasks, job: str, log=print) -> dict[str, str]:
    """{point folder: render group} for the `render` job's points of a rendered scene; `tasks`
    as _run_sweep builds them (row, overrides, input refs, folder)."""
    from poevp_optics.scene.load import load_scene

    if job != "render":
        return {}
    out = {}
    for _row, ov, refs, folder in tasks:
        spec = load_scene(scene, list(ov), cross_checks=False)
        if spec.source.renders:
            out[str(folder)] = render_group(spec.resolved.render, {r.key: r.sha256 for r in refs})
    groups = set(out.values())
    if out:
        log(f"poevp sweep: {len(out)} runs share {len(groups)} render{'s' if len(groups) != 1 else ''} "
            "(radiance rendered once per render and reused)")
    return out


def render_bytes_estimate(specs, seeds: int) -> int:
    """About the disk a sweep's stored renders take: per distinct render (points x seeds, at
    most), per frame (2 K + 2) images of float64 at the render resolution (the guard band left
    out: a lower bound within a few per cent at the shipped sizes)."""
    from poevp_optics.render.render_cache import render_inputs

    seen, total = set(), 0
    for sp in specs:
        rs = sp.resolved.render
        if not rs.source.renders:
            continue
        inputs = render_inputs(rs)
        ident = repr(inputs["scene"]) + repr(inputs["frames"])
        if ident in seen:
            continue
        seen.add(ident)
        h, w = rs.render.resolution
        nodes = sum(len(rs.subframe_times_s(i)) for i in range(rs.timing.frames))
        total += (2 * nodes + 2 * rs.timing.frames) * h * w * 8
    return total * seeds


class RenderReuse:
    """The client's bookkeeping of a sweep's shared renders (module docstring).

    out: the sweep folder. groups: {point folder: render group}. shared: workers read the
    client's paths (LocalCluster, --shared-fs), else stored renders are sent to them."""

    def __init__(self, out: Path, groups: dict[str, str], shared: bool, log=print):
        self.store = Path(out) / "renders"
        self.shared, self.log = shared, log
        clean_stale(self.store)
        self.groups: dict[str, str] = {}
        self.stored: dict[str, list[str]] = {}            # group -> keys of its stored renders
        self.waiting: dict[str, list] = {}                # group -> tasks held back
        self.leaders: dict[str, str] = {}                 # leader's folder -> group
        self._scattered: dict[str, set] = {}              # key -> workers it was pushed to
        self.add_groups(groups)

    def add_groups(self, groups: dict[str, str]) -> None:
        """More points' render groups ({point folder: group}; a search adds each batch's), with
        the complete renders already stored for their groups."""
        for g in set(groups.values()) - set(self.groups.values()):
            for folder in sorted(self.store.glob(f"{g}-g*")) if self.store.is_dir() else ():
                if verify(folder)[0] is not None:
                    self.stored.setdefault(g, []).append(folder.name)
        self.groups.update(groups)

    def group_of(self, task) -> str:
        return self.groups.get(str(task[3]), "")

    def initial(self, todo: list) -> list:
        """The tasks to submit now; the rest wait for their group's leader."""
        now = []
        for t in todo:
            g = self.group_of(t)
            if not g or g in self.stored:
                now.append(t)
            elif g in self.waiting:
                self.waiting[g].append(t)
            else:
                self.leaders[str(t[3])] = g
                self.waiting[g] = []
                now.append(t)
        held = sum(len(v) for v in self.waiting.values())
        if held:
            self.log(f"poevp sweep: {len(self.waiting)} point{'s' if len(self.waiting) != 1 else ''} render first; "
                     f"{held} wait for their render")
        return now

    def finished(self, task, res: dict, client=None) -> list:
        """Take in a render that the point `res` recorded (its path on a shared file system, or
        pulled from its worker in chunks); the tasks its end releases."""
        g = self.group_of(task)
        info = res.get("render") or {}
        folder, why = None, None
        if info.get("stored_at"):
            folder = self.store / info["key"]
            if Path(info["stored_at"]) != folder or verify(folder)[0] is None:
                folder, why = None, f"{info['stored_at']} is not a complete render in {self.store}"
        elif res.get("render_remote") and client is not None:
            folder, why = pull(client, res.pop("render_remote"), self.store, info["key"])
        if why:
            self.log(f"poevp sweep: the render of {task[3].name} did not arrive whole ({why}); its group "
                     "renders again")
        elif folder is not None and folder.name not in self.stored.setdefault(g, []):
            self.stored[g].append(folder.name)
        if self.leaders.pop(str(task[3]), None) is None:
            return []
        return self.waiting.pop(g, [])

    def read_dirs(self) -> tuple[str, ...]:
        """Where a worker finds stored renders itself (shared file system), else nothing."""
        return (str(self.store),) if self.shared else ()

    def store_dir(self) -> str:
        """Where a worker records a render itself (shared file system), else ""."""
        return str(self.store) if self.shared else ""

    def payload(self, client, task) -> list:
        """For workers that do not read the client's paths: the task's group's stored renders
        pushed to every worker that lacks them (`push`, once per render and worker), where the
        point finds them in the worker's inbox (`point_render_cache`). Returns [] (nothing
        travels with the task)."""
        if self.shared:
            return []
        workers = sorted(worker_addresses(client))
        for key in self.stored.get(self.group_of(task), []):
            sent = self._scattered.setdefault(key, set())
            for addr in workers:
                if addr not in sent:
                    if push(client, addr, self.store / key, key):
                        sent.add(addr)
        return []


# ---------------------------------------------------------------------------- moving a render in chunks
#: How often (s) a task pinned to one worker checks that the worker is still in the cluster.
WORKER_CHECK_S = 1.0


class WorkerGone(RuntimeError):
    """The worker a render moves to or from left the cluster."""


def on_worker(client, worker: str, fn, *args):
    """fn(*args) run on `worker` alone; its result. The scheduler keeps a task pinned to a
    worker that left waiting for it for ever, so while the task runs the worker's presence is
    checked every WORKER_CHECK_S: WorkerGone (the task cancelled) once it has left."""
    from distributed import wait

    fut = client.submit(fn, *args, workers=[worker], allow_other_workers=False, pure=False)
    while True:
        try:
            wait([fut], timeout=WORKER_CHECK_S)
            return fut.result()
        except TimeoutError:
            if worker not in worker_addresses(client):
                client.cancel([fut])
                raise WorkerGone(f"worker {worker} left the cluster") from None


def _plain(name: str) -> bool:
    return "/" not in name and "\\" not in name and not name.startswith(".")


def _own_folder(prefix: str) -> Path:
    """tempdir/<prefix><host>-<pid> of this process; those of this host's gone processes are removed."""
    import socket

    from poevp_optics.apps.sweep.bundle import pid_alive

    prefix = f"{prefix}{socket.gethostname().replace('-', '_')}-"
    for old in Path(tempfile.gettempdir()).glob(prefix + "*"):
        pid = old.name[len(prefix):]
        if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)):
            shutil.rmtree(old, ignore_errors=True)
    return Path(tempfile.gettempdir()) / f"{prefix}{os.getpid()}"


def _outbox() -> Path:
    """This worker process's folder of renders it recorded for a client that pulls them."""
    return _own_folder("poevp-renders-")


def read_chunk(path: str, offset: int, size: int) -> bytes:
    """On the worker: `size` bytes of `path` from `offset` (a piece of a render being pulled)."""
    with open(path, "rb") as fh:
        fh.seek(offset)
        return fh.read(size)


def drop_folder(path: str) -> None:
    """On the worker: remove a pulled render's folder from its outbox."""
    if Path(path).parent.name.startswith("poevp-renders-"):
        shutil.rmtree(path, ignore_errors=True)


def pull(client, remote: dict, store: Path, key: str) -> tuple[Path | None, str | None]:
    """A render that a worker recorded in its outbox (`remote`: worker address, folder, [(file,
    size)]), pulled chunk by chunk into a staging folder of `store`, verified and renamed into
    `<store>/<key>`; the worker's copy is then removed. (folder, None) or (None, why)."""
    store.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{key}.staging-{os.getpid()}-", dir=store))
    worker = remote["worker"]
    try:
        for name, size in remote["files"]:
            if not _plain(name):
                return None, f"file {name!r} is not a plain file name"
            with open(stage / name, "wb") as fh:
                for off in range(0, int(size), CHUNK_BYTES):
                    fh.write(on_worker(client, worker, read_chunk, f"{remote['folder']}/{name}", off, CHUNK_BYTES))
        man, why = verify(stage)
        if man is None:
            return None, why
        return install(stage, store / key), None
    except Exception as e:  # noqa: BLE001 - a worker gone mid-pull: the group renders again
        return None, f"{type(e).__name__}: {e}"
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)
        try:
            on_worker(client, worker, drop_folder, remote["folder"])
        except Exception:  # noqa: BLE001 - the worker is gone, and its outbox with it at its next start
            pass


def _inbox() -> Path:
    """This worker process's folder of stored renders a client pushed to it; those of this
    host's worker processes that are gone are removed first."""
    return _own_folder("poevp-inbox-")


def write_chunk(key: str, name: str, offset: int, data: bytes) -> None:
    """On the worker: a piece of file `name` of render `key` at `offset`, into the inbox."""
    folder = _inbox() / f".{key}.incoming"
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    with open(path, "r+b" if path.exists() else "wb") as fh:
        fh.seek(offset)
        fh.write(data)


def finish_push(key: str) -> bool:
    """On the worker: the pushed render `key` verified and renamed into the inbox (else removed)."""
    stage = _inbox() / f".{key}.incoming"
    try:
        if verify(stage)[0] is None:
            return False
        install(stage, _inbox() / key)
        return True
    finally:
        if stage.exists():
            shutil.rmtree(stage, ignore_errors=True)


def push(client, worker: str, folder: Path, key: str) -> bool:
    """The stored render `folder` pushed to `worker`'s inbox in chunks of CHUNK_BYTES, one in the
    client's memory at a time (module docstring); whether it arrived whole."""
    try:
        for p in sorted(folder.iterdir()):
            if p.is_file() and not p.is_symlink():
                with open(p, "rb") as fh:
                    off = 0
                    while chunk := fh.read(CHUNK_BYTES):
                        on_worker(client, worker, write_chunk, key, p.name, off, chunk)
                        off += len(chunk)
        return bool(on_worker(client, worker, finish_push, key))
    except Exception:  # noqa: BLE001 - a worker gone meanwhile: its points render for themselves
        return False


def point_render_cache(task, renders, work: Path):
    """On the worker: the point's RenderCache (render/render_cache.py) for a sweep.PointTask
    with a render group: the stored renders it reads (the client's folder, or the ones pushed
    into this worker's inbox) and where it records its own (the client's store on a shared file
    system, else this process's outbox); None without a group."""
    if not task.render_group:
        return None
    from poevp_optics.render.render_cache import RenderCache

    read = tuple(map(Path, task.render_read)) if task.render_store else (*map(Path, task.render_read), _inbox())
    store = Path(task.render_store) if task.render_store else _outbox()
    return RenderCache(task.render_group, read, store, task.label)


def render_result(cache, shared: bool) -> dict:
    """run_point's "render" entry: the render it used and, for a render this point recorded, its
    path in the shared store (`stored_at`) or, off a shared file system, where the client pulls
    it from (`render_remote`: this worker, the folder, its files and their sizes)."""
    if cache is None:
        return {}
    o = cache.outcome
    out = {"render": {k: o[k] for k in ("key", "reused", "rendered_by")}}
    if o.get("stored"):
        folder = Path(o["stored"])
        if shared:
            out["render"]["stored_at"] = str(folder)
        else:
            from distributed import get_worker

            out["render_remote"] = {"worker": get_worker().address, "folder": str(folder),
                                    "files": [(p.name, p.stat().st_size) for p in sorted(folder.iterdir())
                                              if p.is_file()]}
    return out


def reuse_columns(reuse: RenderReuse | None, res: dict) -> dict:
    """A finished point's table columns for its render (REUSE_COLUMNS), from run_point's result;
    every row of a sweep that shares renders has them (a failed point: "", False, "")."""
    if reuse is None or not reuse.groups:
        return {}
    info = res.get("render") or {}
    return {"render_key": info.get("key") or "", "render_reused": bool(info.get("reused")),
            "render_by": info.get("rendered_by") or ""}


def columns_from_report(folder: Path, report: dict) -> dict:
    """The render columns of a point rebuilt from its report (`--rebuild`): the key its report
    names, and who rendered it from the stored render's manifest in the sweep's renders/
    (`folder` is the point's folder, points/<name>); {} for a report without a render key."""
    import json

    key = (report.get("render_reuse") or {}).get("key")
    if not key:
        return {}
    try:
        by = json.loads((folder.parent.parent / "renders" / key / "manifest.json").read_text()).get("rendered_by") or ""
    except (OSError, ValueError):
        by = ""
    return {"render_key": key, "render_reused": bool(by) and by != folder.name, "render_by": by}
