"""The scene-key reference, generated from the params dataclasses and their registries.

Every key a scene.toml may hold is a field of a section's frozen params dataclass
(scene/spec.py `SECTIONS`, `TABLE_SECTIONS`, `TOP_KEYS`; nested dataclasses such as
`[dmd.registration]` are sub-tables). For each key this module gathers, from the code alone:

* type, default and range from the field (`core.params.param`: min, max, gt, lt, unset, why);
* choices from the field's `choices`; a `core.registry.Registry` gives each choice its cited
  `source`;
* unit and meaning from the owner module's docstring key table (`| key | type | unit | ... |`),
  else the field's trailing comment, else the key's unit suffix (`_s` s, `_m` m, `_hz` Hz, ...,
  the naming convention of core/units.py);
* for `[source]`, which kinds take the key (`sources.kinds.SOURCES[kind].keys`).

`python -m poevp_optics.scene.reference [PATH]` writes the Markdown page (stdout without PATH);
the documentation build (docs/hooks.py) generates docs/reference/scene_keys.md from it, and
scene/schema.py builds the JSON Schema of scene.toml from the same `KeyInfo`s.
"""

from __future__ import annotations

import ast
import dataclasses
import inspect
import io
import math
import re
import sys
import textwrap
import tokenize
from dataclasses import dataclass
from typing import Any, get_args, get_origin, get_type_hints

from poevp_optics.core.registry import Registry

#: Unit of a key by its name's suffix (longest first): the units convention of core/units.py
#: and the module tables (`_s` seconds, `_m` metres, `_e` electrons, `_dn` digital numbers).
SUFFIX_UNITS = (
    ("_cd_per_m2", "cd m-2"), ("_m_per_s", "m s-1"), ("_e_per_s", "e- s-1"), ("_dn_per_e", "DN e-1"),
    ("_hz", "Hz"), ("_deg", "deg"), ("_px", "px"), ("_nm", "nm"), ("_lux", "lx"), ("_cd", "cd"),
    ("_bits", "bit"), ("_dn", "DN"), ("_e", "e-"), ("_s", "s"), ("_m", "m"),
)

#: Meanings of the keys whose module says nothing about them in a key table or a comment (the
#: name alone is not enough); everything else on the page comes from the code.
NOTES = {
    "render.xml": "the Mitsuba 3 scene file, relative to the scene's folder",
    "render.spp": "samples per pixel per radiance sample (split over `mc_splits` independent-seed renders)",
    "render.resolution": "[height, width] of the sensor image (and the mirror grid's field)",
    "render.seed": "seed of the Monte Carlo renders (reproducible runs)",
    "render.spectral_mode": "`spectral` (Mitsuba samples wavelengths), `mono` (pre-integrated: exact for one SPD "
                            "or flat reflectances), `auto` (mono where exact; the report says which ran and why)",
    "dmd.enabled": "false: no DMD in the path (the sensor sees the objective's image directly)",
    "dmd.pitch_m": "mirror pitch (DLP6500: 7.56 um)",
    "dmd.registration": "mirror grid to sensor grid mapping (camera/registration.py)",
    "dmd.registration.scale": "sensor pixels per mirror",
    "dmd.registration.rotation_deg": "rotation of the mirror grid on the sensor",
    "dmd.registration.offset_px": "[y, x] shift of the mirror grid on the sensor",
    "relay.psf": "relay PSF model (`PSFS`)",
    "relay.sigma_px": "sigma of the `gaussian` PSF",
    "relay.measured_file": "PSF image (PNG/EXR, sensor-pixel sampling) for psf = 'measured', from the scene folder or assets/",
    "relay.transmission": "relay lens transmission",
    "relay.glare_sigma_px": "sigma of the relay's Gaussian veiling-glare halo",
    "sensor.preset": "sensor by name (`SENSOR_PRESETS`); the keys below override its values",
    "sensor.full_well_e": "full-well capacity",
    "sensor.read_noise_e": "read noise, rms",
    "sensor.gain_dn_per_e": "conversion gain (signal_dn = offset_dn + gain_dn_per_e x electrons)",
    "sensor.offset_dn": "black level",
    "sensor.dark_current_e_per_s": "dark current",
    "sensor.prnu": "photo-response non-uniformity, fraction (rms)",
    "sensor.dsnu_e": "dark-signal non-uniformity, rms",
    "sensor.pixel_pitch_m": "pixel pitch",
    "sensor.f_number": "working f-number at the sensor",
    "sensor.optical_throughput": "transmission of the optics before the sensor (fraction)",
    "sensor.qe": "quantum-efficiency table (a sources/spectra.py source); empty: the preset's",
    "sensor.noise": "false: no shot, read or fixed-pattern noise (deterministic captures)",
    "sensor.seed": "seed of the sensor's noise",
    "mask.law": "mask law (`MASK_LAWS`): predicted frame -> DMD levels",
    "mask.vs": "paper Eq. 2 threshold Vs (8-bit scale)",
    "mask.a": "paper Eq. 2 coefficient a",
    "mask.b": "paper Eq. 2 coefficient b",
    "mask.target": "`target` / `exposure_controller` aim: signal as a fraction of full scale",
    "mask.band_high": "exposure_controller: top of the band, fraction of full scale",
    "sensor.bits": "ADC bits",
    "render.sampler": "Mitsuba sampler (`SAMPLERS`)",
    "render.light_selection": "emitter sampling weights (`LIGHT_SELECTIONS`)",
    "render.target_rel_error": "Monte Carlo error target (ROI, or frame)",
    "mask.smooth_px": "sigma of the band-limiting blur before any law (the envelope keeps the mask >= the frame)",
    "mask.envelope": ("the envelope's radius: `fixed` ceil(3 smooth_px) mirrors; `predictor_error` how far the "
                      "last captured highlight reached beyond the bright region its mask aimed at, as the "
                      "envelope's sigma within [1, smooth_px] mirrors (control/masks.py); `region_body` each bright "
                      "region's body (its median demand) at the fixed radius, its brighter parts at half its own "
                      "last miss (exposure_controller only: control/envelope.py)"),
    "predictor.name": "video predictor (`PREDICTORS`)",
    "predictor.resolution": "[height, width] the predictor runs at",
    "loop.mode": "what the predictor sees (`LOOP_MODES`)",
    "loop.init_frames": "all-white frames that start the loop",
    "outputs.radiance_exr": "write radiance/frame_NNNN.exr (the ground truth)",
    "outputs.subframes_exr": "write each exposure's radiance samples (subframes/)",
    "outputs.previews": "write tone-mapped previews of the truth and the reconstruction",
    "outputs.contact_sheet": "write contact_sheet.png",
    "outputs.tonemap": "tone mapper of the previews (`TONEMAPPERS`)",
    "plate.text": "plate characters; empty: the XML's own texture",
    "plate.param": "the XML texture parameter `$<param>` the generated plate is bound to",
    "plate.format": "plate size and layout: `eu` 520 x 110 mm, `us` 305 x 152 mm (the XML's plate must have this size)",
    "plate.band": "draw the EU's blue field at the left (format `eu` only)",
    "plate.width_px": "width of the generated plate texture (0: the format's width at 2 px/mm)",
    "plate.height_px": "height of the generated plate texture (0: the format's height at 2 px/mm)",
    "chart.patches": "number of patches (0: not a chart)",
    "chart.d_min": "density of the first patch (equal steps to d_max)",
    "chart.d_max": "density of the last patch",
    "chart.densities": "explicit densities, one per patch (instead of d_min..d_max)",
    "chart.source": "SPD of the light box (a sources/spectra.py source)",
    "chart.luminance_cd_per_m2": "luminance of the bare light box",
    "chart.param_prefix": "patch i is bound to the XML parameter `$<param_prefix>NN`",
    "chart.mask_source": "the mask the chart is captured with: the closed `loop` settled, or the `oracle`'s",
    "source.kind": "where the radiance comes from (`SOURCES`)",
    "source.transfer": "ldr_highlight: decoding of the stored values (`TRANSFERS`)",
    "source.gamma": "ldr_highlight: exponent of transfer = 'gamma'",
    "source.radius_rule": "ldr_highlight: Eq. 3's R -> the Gaussian's sigma (`RADIUS_RULES`)",
    "source.reference_frame": "exr_sequence `relative`: the frame (sorted index) of `reference_pixel`",
    "source.video": "ldr_highlight: one video file (OpenCV) instead of `frames`",
    "attenuator.kind": "`none` or a variable ND before the DMD (`ATTENUATORS`)",
    "budget.compute": "predictor + mask-law time: a device budget (`COMPUTE_BUDGETS`)",
    "motion.kind": "`linear`, `keyframes` or `static`",
    "spectra.kind": "`intensity` (scaled by intensity_cd), `radiance` (luminance_cd_per_m2), "
                    "`irradiance` (illuminance_lux) or `reflectance` (times `scale`, <= 1)",
    "spectra.source": "the spectrum: `cie:<illuminant>`, `colorchecker:<patch>`, `file:<csv>`, `neutral:<v>` "
                      "(sources/spectra.py)",
    "spectra.intensity_cd": "kind = 'intensity': peak luminous intensity",
    "spectra.luminance_cd_per_m2": "kind = 'radiance': luminance",
    "spectra.illuminance_lux": "kind = 'irradiance': illuminance",
    "spectra.scale": "kind = 'reflectance': factor on the table (the result must stay <= 1)",
    "spectra.distribution": "kind = 'intensity': photometric file (.ies / .ldt) shaping the lamp",
    "flicker.frequency_hz": "PWM frequency of the lamp's drive",
    "flicker.duty": "on fraction of each period",
    "flicker.phase_s": "start of the first on-phase",
    "flicker.off_fraction": "drive level during the off-phase (0: fully off)",
    "sheeting.source": "R_A table: `astm_d4956:I`, `:II`, `:III`, `en12899_1:RA1`, `:RA2` (signs), "
                       "`en1463_1:PRP1` (road studs), or `file:<csv>`",
    "sheeting.efficiency": "retroreflective efficiency bound (NaN: the preset's, 10 %)",
}

#: Meanings of the top-level keys (scene/spec.py TOP_KEYS).
TOP_NOTES = {"description": "one line saying what the scene is (shown by `poevp validate`)"}

#: How a section's own table is described on the page (its params class docstring, first line).
_MISSING = dataclasses.MISSING


@dataclass(frozen=True)
class KeyInfo:
    """One scene key: where it lives, its type, unit, default, bounds, choices and meaning."""

    section: str                 # "render", "motion.<id>", "dmd.registration"
    name: str
    tp: Any                      # the field's Python type
    default: Any                 # dataclasses.MISSING: required
    meta: dict
    unit: str
    description: str
    owner: str                   # module that owns the params class
    choices: tuple[tuple[str, str], ...] = ()   # (name, cited source; "" for a plain tuple)
    registry: str = ""           # the Registry's `what`, when the choices come from one
    kinds: tuple[str, ...] = ()  # [source] keys: the kinds that take it

    @property
    def key(self) -> str:
        return f"{self.section}.{self.name}"

    @property
    def generic_key(self) -> str:
        """The key with a table section's id dropped (`motion.<id>.kind` -> `motion.kind`)."""
        return self.key.replace(".<id>", "").replace(".<param>", "")

    @property
    def required(self) -> bool:
        return self.default is _MISSING

    @property
    def is_table(self) -> bool:
        return dataclasses.is_dataclass(self.tp)


# --- reading the code --------------------------------------------------------------------------

def field_comments(cls) -> dict[str, str]:
    """Trailing `#` comments of a dataclass's fields (and comment-only lines right after a
    field, which continue it), by field name."""
    try:
        lines, _ = inspect.getsourcelines(cls)
    except (OSError, TypeError):
        return {}
    src = textwrap.dedent("".join(lines))
    tree = ast.parse(src)
    body = tree.body[0].body
    spans = {}
    for i, node in enumerate(body):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            nxt = body[i + 1].lineno - 1 if i + 1 < len(body) else node.end_lineno
            spans[node.target.id] = (node.lineno, node.end_lineno, nxt)
    comments: dict[int, str] = {}
    code_lines: set[int] = set()
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string.lstrip("#").strip()
        elif tok.type not in (tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
                              tokenize.ENDMARKER):
            code_lines.add(tok.start[0])
    out = {}
    for name, (first, last, nxt) in spans.items():
        parts = [comments[n] for n in range(first, last + 1) if n in comments]
        n = last + 1
        while n <= nxt and n in comments and n not in code_lines:
            parts.append(comments[n])
            n += 1
        if parts:
            out[name] = " ".join(parts)
    return out


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def docstring_tables(doc: str | None) -> dict[str, dict[str, str]]:
    """Rows of the Markdown key tables in a module docstring (first column `key` or `property`):
    key -> {column name: cell}."""
    out: dict[str, dict[str, str]] = {}
    lines = (doc or "").splitlines()
    i = 0
    while i < len(lines):
        head = _cells(lines[i]) if lines[i].strip().startswith("|") else []
        if head and head[0].lower() in ("key", "property") and i + 1 < len(lines) \
                and set(lines[i + 1].strip()) <= set("|-: "):
            cols = [h.lower() for h in head]
            i += 2
            while i < len(lines) and lines[i].strip().startswith("|"):
                row = _cells(lines[i])
                key = row[0].strip("`")
                out.setdefault(key, dict(zip(cols, row)))
                i += 1
        else:
            i += 1
    return out


def _table_meaning(row: dict[str, str]) -> str:
    for col in ("meaning", "what", "source / meaning"):
        if row.get(col):
            return row[col]
    return ""


def unit_of(name: str, row: dict[str, str] | None) -> str:
    """A key's unit: its module table's `unit` column, else its name's suffix, else '-'."""
    if row and row.get("unit") and row["unit"] not in ("", "-"):
        return row["unit"]
    for suffix, unit in SUFFIX_UNITS:
        if name.endswith(suffix):
            return unit
    return "-"


def _choices(meta: dict) -> tuple[tuple[tuple[str, str], ...], str]:
    ch = meta.get("choices")
    if ch is None:
        return (), ""
    if isinstance(ch, Registry):
        return tuple((n, ch.entry(n).source) for n in ch.names()), ch.what
    return tuple((str(n), "") for n in ch), ""


def _source_kinds() -> dict[str, tuple[str, ...]]:
    from poevp_optics.sources.kinds import SOURCES

    by_key: dict[str, list[str]] = {}
    for kind in SOURCES.names():
        for k in SOURCES[kind].keys:
            by_key.setdefault(k, []).append(kind)
    return {k: tuple(v) for k, v in by_key.items()}


def _source_kinds_all() -> tuple[str, ...]:
    from poevp_optics.sources.kinds import SOURCES

    return SOURCES.names()


#: The package's folders along the chain (DESIGN.md): a params class in one of them is tabled in
#: its own module; one in a package below them (a stage split into modules) anywhere in it.
CHAIN_FOLDERS = ("poevp_optics", "core", "scene", "sources", "render", "materials", "camera", "control",
                 "predictors", "analysis", "apps")


def _tables_for(cls) -> dict[str, dict[str, str]]:
    """The docstring key tables that describe `cls`'s fields: its module's (its package's, for a
    stage that is a package), and for [source] the kind modules' (each kind tables its own keys)."""
    rows = docstring_tables(sys.modules[cls.__module__].__doc__)
    package = cls.__module__.rpartition(".")[0]
    if package.rpartition(".")[2] not in CHAIN_FOLDERS:      # a stage split into a package
        for name in sorted(m for m in list(sys.modules) if m == package or m.startswith(package + ".")):
            for key, row in docstring_tables(sys.modules[name].__doc__).items():
                rows.setdefault(key, row)
    if cls.__name__ == "SourceSpec":
        from poevp_optics.sources.kinds import SOURCES

        for kind in SOURCES.names():
            for name, row in docstring_tables(inspect.getmodule(SOURCES[kind].check_keys).__doc__).items():
                rows.setdefault(name, row)
    return rows


def class_keys(cls, section: str, generic: str) -> list[KeyInfo]:
    """KeyInfos of one params class (recursing into nested dataclasses); `generic`: the
    section as NOTES names it (table ids dropped)."""
    hints = get_type_hints(cls)
    comments = field_comments(cls)
    rows = _tables_for(cls)
    kinds = _source_kinds() if cls.__name__ == "SourceSpec" else {}
    out = []
    for f in dataclasses.fields(cls):
        tp = hints[f.name]
        row = rows.get(f.name)
        note, comment = NOTES.get(f"{generic}.{f.name}", ""), comments.get(f.name, "")
        desc = (_table_meaning(row) if row else "") or note or comment
        if desc == note and comment and comment not in note:
            desc = f"{note} ({comment})"
        if row and row.get("kind") == "accuracy":
            desc += " (accuracy setting)"
        if dataclasses.is_dataclass(tp):
            desc = desc or (inspect.getdoc(tp) or "").split("\n")[0]
        choices, reg = _choices(f.metadata)
        out.append(KeyInfo(section=section, name=f.name, tp=tp, default=f.default, meta=dict(f.metadata),
                           unit=unit_of(f.name, row) if not dataclasses.is_dataclass(tp) else "-",
                           description=desc, owner=cls.__module__, choices=choices, registry=reg,
                           kinds=kinds.get(f.name, tuple(_source_kinds_all()) if f.name == "kind" and kinds else ())))
        if dataclasses.is_dataclass(tp):
            out.extend(class_keys(tp, f"{section}.{f.name}", f"{generic}.{f.name}"))
    return out


TABLE_IDS = {"motion": "<id>", "spectra": "<param>", "flicker": "<param>", "sheeting": "<param>", "marking": "<param>"}


def sections() -> list[tuple[str, type, bool]]:
    """(section as written in the TOML, params class, is a table of named entries)."""
    from poevp_optics.scene.spec import SECTIONS, TABLE_SECTIONS

    return [(n, c, False) for n, c in SECTIONS.items()] + \
           [(f"{n}.{TABLE_IDS.get(n, '<id>')}", c, True) for n, c in TABLE_SECTIONS.items()]


def all_keys() -> list[KeyInfo]:
    """Every scene key, section by section (scene/spec.py order)."""
    out = []
    for sec, cls, _ in sections():
        out.extend(class_keys(cls, sec, sec.split(".")[0]))
    return out


# --- presenting --------------------------------------------------------------------------------

def toml_value(v: Any) -> str:
    """A default as it would be written in TOML ('not set' for the NaN of "not given")."""
    if v is _MISSING:
        return "required"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if math.isnan(v):
            return "not set"
        return repr(v) if len(repr(v)) <= 8 else f"{v:.6g}"
    if isinstance(v, str):
        return f'"{v}"'
    if isinstance(v, tuple):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if dataclasses.is_dataclass(v):
        return "table"
    return str(v)


def type_name(tp) -> str:
    """The TOML type of a field: integer, float, boolean, string, array of ..., table."""
    if dataclasses.is_dataclass(tp):
        return "table"
    if get_origin(tp) is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            inner = type_name(args[0])
            return f"array of {inner.replace('array', 'arrays', 1)}" if inner.startswith("array") \
                else f"array of {inner}s"
        inner = {type_name(a) for a in args}
        return f"array of {len(args)} {inner.pop()}s" if len(inner) == 1 else "array"
    return {int: "integer", float: "float", bool: "boolean", str: "string"}[tp]


def _num(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def range_text(k: KeyInfo) -> str:
    """The bounds of a number (of each element of an array) as an interval."""
    m = k.meta
    lo = ("[", _num(m["min"])) if "min" in m else ("(", _num(m["gt"])) if "gt" in m else None
    hi = (_num(m["max"]), "]") if "max" in m else (_num(m["lt"]), ")") if "lt" in m else None
    if lo and hi:
        text = f"{lo[0]}{lo[1]}, {hi[0]}{hi[1]}"
    elif lo:
        text = f"{'>=' if lo[0] == '[' else '>'} {lo[1]}"
    elif hi:
        text = f"{'<=' if hi[1] == ']' else '<'} {hi[0]}"
    else:
        return ""
    if get_origin(k.tp) is tuple:
        text = f"each {text}"
    if "unset" in m:
        text += f", or {_num(m['unset'])}: not set"
    return text


def _md(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown() -> str:
    """The reference page (Markdown, for MkDocs)."""
    from poevp_optics.scene.spec import TOP_KEYS

    keys = all_keys()
    by_sec: dict[str, list[KeyInfo]] = {}
    for k in keys:
        by_sec.setdefault(k.section, []).append(k)
    out = ["# Scene keys", "",
           "<!-- generated by poevp_optics/scene/reference.py from the params dataclasses and their "
           "registries: do not edit -->", "",
           "Every key a `scene.toml` may hold, generated from the params dataclasses that validate it "
           "(`scene/spec.py` names which class owns which section) and the registries their choices come "
           "from. A key not listed here is refused with one line naming the file and the key. "
           "`poevp schema` writes the same information as a JSON Schema for editors "
           "([guide](../guides/own-scene.md#editor-completion)).", "",
           "Ranges are intervals (`[` `]` inclusive, `(` `)` exclusive); on an array they bound each "
           "element. *not set* is a NaN default: the value then comes from elsewhere (the preset, the "
           "optical layout), as the description says. Units: `-` for dimensionless values.", "",
           "## Top level", "", "| key | type | meaning |", "|---|---|---|"]
    for t in sorted(TOP_KEYS):
        out.append(f"| `{t}` | string | {TOP_NOTES.get(t, '')} |")
    out.append("")
    for sec, cls, is_table in sections():
        out += _section_md(sec, cls, is_table, by_sec)
    return "\n".join(out) + "\n"


def _best_loop_md(sec: str) -> list[str]:
    """The note on a loop section whose defaults depend on its choosing key (scene/defaults.py)."""
    from poevp_optics.scene.defaults import BEST_LOOP, PREDICTION_FREE_LAWS, ROAD_ONLY

    if sec not in BEST_LOOP:
        return []
    choosing, values = BEST_LOOP[sec]
    vals = ", ".join(f"`{k} = {toml_value(v)}`" for k, v in values.items())
    road = ROAD_ONLY.get(sec)
    extra = (" On a `[road]` scene also " + ", ".join(f"`{k} = {toml_value(v)}`" for k, v in road.items()) + "."
             if road else "")
    if sec != "mask":
        extra += (" A scene whose mask law reads no prediction (" + ", ".join(f"`{x}`" for x in PREDICTION_FREE_LAWS)
                  + ") runs no predictor and gets none of these.")
    return ["", f"**Default loop.** A scene with a DMD that does not set `{sec}.{choosing}` gets the project's "
                f"best causal loop for every key of this section it leaves out: {vals}.{extra} A scene that "
                f"sets `{choosing}` gets the defaults in the table below; the run's report lists what was "
                "applied (`defaults_applied`)."]


def _section_md(sec: str, cls, is_table: bool, by_sec: dict) -> list[str]:
    doc = (inspect.getdoc(cls) or "").split("\n\n")[0].replace("\n", " ")
    out = [f"## [{sec}]", "", f"{_md(doc)} Owner: `{cls.__module__}.{cls.__name__}`."]
    if is_table:
        out.append(f"Any number of entries, each a table `[{sec}]` with the keys below.")
    out += _best_loop_md(sec)
    out.append("")
    for sub in [s for s in by_sec if s == sec or s.startswith(sec + ".")]:
        rows = by_sec[sub]
        if sub != sec:
            out += [f"### [{sub}]", ""]
        head = "| key | type | unit | default | range | meaning |"
        if cls.__name__ == "SourceSpec":
            head = "| key | type | unit | default | range | kinds | meaning |"
        out += [head, "|" + "---|" * (head.count("|") - 1)]
        for k in rows:
            if k.is_table:
                cells = [f"`{k.name}`", "table", "-", "-", "", _md(k.description) + f" (`[{k.key}]` below)"]
            else:
                cells = [f"`{k.name}`", type_name(k.tp), _md(k.unit), f"`{toml_value(k.default)}`"
                         if k.default is not _MISSING else "**required**", range_text(k), _md(k.description)]
            if cls.__name__ == "SourceSpec":
                cells.insert(5, ", ".join(k.kinds) if k.kinds else "-")
            out.append("| " + " | ".join(cells) + " |")
        out.append("")
        for k in rows:
            if k.choices:
                what = f" (registry: {k.registry})" if k.registry else ""
                out.append(f"Choices of `{k.generic_key}`{what}:")
                out.append("")
                for name, source in k.choices:
                    out.append(f"- `{name}`" + (f": {source}" if source else ""))
                out.append("")
            if "why" in k.meta:
                out += [f"Bound of `{k.generic_key}`: {k.meta['why']}.", ""]
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    text = markdown()
    if argv:
        from pathlib import Path

        Path(argv[0]).parent.mkdir(parents=True, exist_ok=True)
        Path(argv[0]).write_text(text)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
