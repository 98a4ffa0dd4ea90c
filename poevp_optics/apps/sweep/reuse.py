"""Radiance rendered once per sweep: which points share a render, when each point may start, and
where the stored renders live (render/render_cache.py holds the key recipe and the store).

A point's *render group* is `render_group` of its resolved render inputs with the SHA-256 of the
files it reads (computed here on the client, where every point's files are hashed already); a
`render` job point of a Mitsuba scene has one, a chart point or a frame source's has none. The
first point of each group that has no stored render (the *leader*) runs first and records its
render; the group's other points are held back until it ends, then run and replay the stored
render (or record their own, when the camera's guard band, and so the render's key, differs).
A leader that fails releases its group: each point then renders for itself. The stored renders
live in the sweep's folder, `renders/<group>-g<guard_px>/`: a worker writes only into its
temporary folder, so a recording comes back to the client as zip bytes with the point's outputs
(as they do) and the client puts it in place (checked, staged, renamed). Workers read them from
there on a LocalCluster or with --shared-fs (checksums verified on each read); otherwise the
client sends each stored render to the workers that need it (Dask scatter, once per render).
The table's columns `render_key`, `render_reused` and `render_by` say which render each point
used, whether it replayed a stored one, and which point folder rendered it.
"""

from __future__ import annotations

from pathlib import Path

from poevp_optics.render.render_cache import clean_stale, render_group, unpack, verify

#: The results table's columns for reuse (module docstring).
REUSE_COLUMNS = ("render_key", "render_reused", "render_by")


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
        self._scattered: dict[str, object] = {}           # key -> Dask future of its bytes
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

    def finished(self, task, res: dict) -> list:
        """Store a recording that came back with `res`; the tasks its end releases."""
        g = self.group_of(task)
        data = res.pop("render_archive", None)
        info = res.get("render") or {}
        if data is not None and info.get("key"):
            folder, why = unpack(data, self.store, info["key"])
            if folder is None:
                self.log(f"poevp sweep: the render of {task[3].name} did not arrive whole ({why}); its group "
                         "renders again")
            elif folder.name not in self.stored.setdefault(g, []):
                self.stored[g].append(folder.name)
        if self.leaders.pop(str(task[3]), None) is None:
            return []
        return self.waiting.pop(g, [])

    def read_dirs(self) -> tuple[str, ...]:
        """Where a worker finds stored renders itself (shared file system), else nothing."""
        return (str(self.store),) if self.shared else ()

    def payload(self, client, task) -> list:
        """[(key, future of its bytes)] of the task's group's stored renders, for workers that
        do not read the client's paths (scattered once per render)."""
        if self.shared:
            return []
        from poevp_optics.render.render_cache import pack

        out = []
        for key in self.stored.get(self.group_of(task), []):
            if key not in self._scattered:
                self._scattered[key] = client.scatter(pack(self.store / key), hash=True)
            out.append((key, self._scattered[key]))
        return out


def point_render_cache(task, renders, work: Path):
    """On the worker: the point's RenderCache (render/render_cache.py) for a sweep.PointTask
    with a render group: the stored renders it reads (the client's folder, or the ones sent,
    unpacked into `work`) and its own store; None without a group."""
    if not task.render_group:
        return None
    from poevp_optics.render.render_cache import RenderCache, unpack

    store = work / "renders"
    for key, data in renders or ():
        unpack(data, store, key)
    return RenderCache(task.render_group, (*map(Path, task.render_read), store), store, task.label)


def render_result(cache) -> dict:
    """run_point's "render" entry and, for a render this point made, its zip."""
    if cache is None:
        return {}
    from poevp_optics.render.render_cache import pack

    o = cache.outcome
    out = {"render": {k: o[k] for k in ("key", "reused", "rendered_by")}}
    if o.get("stored"):
        out["render_archive"] = pack(Path(o["stored"]))
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
