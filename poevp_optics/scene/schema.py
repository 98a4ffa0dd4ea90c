"""JSON Schema (draft 2020-12) of scene.toml, from the params dataclasses (`poevp schema`).

Built from the same `reference.KeyInfo`s as the scene-key reference page: TOML types, enums
from the registries (as registered when the schema is written), min / max (exclusive for `gt`,
`lt`), required keys, `additionalProperties: false` wherever the loader refuses unknown keys (top
level, every section, every table entry), and per `[source] kind` the keys that kind takes
(scene/validate.py `check_source`). Descriptions carry the unit and the default, so an editor
(taplo / Even Better TOML: `#:schema ./scene.schema.json` on the first line, or a schema
association) completes and checks keys. Only keywords of draft 7 and later's common core are
used (`items` with min/maxItems for fixed-length arrays, `const`, `if`/`then`, `propertyNames`),
so older validators read it too. Checks that combine keys or read files (timing fits
the frame, spectra resolve, files exist) stay with `poevp validate`.

Reference: JSON Schema draft 2020-12, https://json-schema.org/draft/2020-12/json-schema-core
and json-schema-validation.
"""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any, get_args, get_origin

from poevp_optics.scene.reference import TOP_NOTES, KeyInfo, all_keys, sections, toml_value

DIALECT = "https://json-schema.org/draft/2020-12/schema"


def _type_schema(tp, meta: dict) -> dict:
    """Schema of one value of Python type `tp` with the field's bounds (on each element of an
    array, as core.params checks them)."""
    if get_origin(tp) is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return {"type": "array", "items": _type_schema(args[0], meta)}
        if len(set(args)) == 1:             # homogeneous (every fixed tuple here): `items`, valid in drafts 6-2020-12
            return {"type": "array", "items": _type_schema(args[0], meta),
                    "minItems": len(args), "maxItems": len(args)}
        return {"type": "array", "prefixItems": [_type_schema(a, meta) for a in args],
                "minItems": len(args), "maxItems": len(args), "items": False}
    if tp is bool:
        return {"type": "boolean"}
    if tp is str:
        out: dict[str, Any] = {"type": "string"}
        if "choices" in meta:
            out["enum"] = [str(c) for c in meta["choices"]]
        return out
    if tp in (int, float):
        out = {"type": "integer" if tp is int else "number"}
        for k, js in (("min", "minimum"), ("max", "maximum"), ("gt", "exclusiveMinimum"),
                      ("lt", "exclusiveMaximum")):
            if k in meta:
                out[js] = meta[k]
        if "unset" in meta:
            return {"anyOf": [out, {"const": meta["unset"]}]}
        return out
    raise TypeError(f"unsupported field type {tp}")


def _json_default(v: Any):
    if isinstance(v, float) and math.isnan(v):
        return None
    if isinstance(v, tuple):
        return [_json_default(x) for x in v]
    return v


def _key_schema(k: KeyInfo, nested: dict[str, list[KeyInfo]]) -> dict:
    if k.is_table:
        out = _object_schema(nested[k.key], nested)
    else:
        out = _type_schema(k.tp, k.meta)
        d = _json_default(k.default) if k.default is not dataclasses.MISSING else None
        if d is not None:
            out["default"] = d
    unit = f" [{k.unit}]" if k.unit not in ("", "-") else ""
    default = f" Default: {toml_value(k.default)}." if not k.is_table else ""
    out["description"] = f"{k.description}{unit}.{default}".replace("..", ".")
    if k.choices and any(src for _, src in k.choices):
        out["description"] += " Choices: " + "; ".join(f"{n}: {s}" if s else n for n, s in k.choices)
    return out


def _object_schema(keys: list[KeyInfo], nested: dict[str, list[KeyInfo]]) -> dict:
    out = {"type": "object", "properties": {k.name: _key_schema(k, nested) for k in keys},
           "additionalProperties": False}
    req = [k.name for k in keys if k.required]
    if req:
        out["required"] = req
    return out


def _source_kinds_rule(keys: list[KeyInfo]) -> list[dict]:
    """Per kind, the [source] keys it takes (kind = 'mitsuba', the default, takes none)."""
    from poevp_optics.sources.kinds import SOURCES

    rules = []
    for kind in SOURCES.names():
        allowed = ["kind", *SOURCES[kind].keys]
        cond = {"properties": {"kind": {"const": kind}}}
        if kind == "mitsuba":
            cond = {"anyOf": [cond | {"required": ["kind"]}, {"not": {"required": ["kind"]}}]}
        else:
            cond["required"] = ["kind"]
        rules.append({"if": cond, "then": {"propertyNames": {"enum": allowed}}})
    return rules


def scene_schema() -> dict:
    """The JSON Schema of a scene.toml (module docstring)."""
    keys = all_keys()
    by_sec: dict[str, list[KeyInfo]] = {}
    for k in keys:
        by_sec.setdefault(k.section, []).append(k)
    from poevp_optics.scene.spec import TOP_KEYS

    props: dict[str, Any] = {t: {"type": "string", "description": TOP_NOTES.get(t, "")} for t in sorted(TOP_KEYS)}
    for sec, cls, is_table in sections():
        doc = (cls.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        body = _object_schema(by_sec[sec], by_sec)
        if cls.__name__ == "SourceSpec":
            body["allOf"] = _source_kinds_rule(by_sec[sec])
        if is_table:
            name = sec.split(".")[0]
            props[name] = {"type": "object", "description": doc, "additionalProperties": body}
        else:
            body["description"] = doc
            props[sec] = body
    return {"$schema": DIALECT, "title": "poevp_optics scene.toml",
            "description": "A poevp scene (scenes/<name>/scene.toml); generated by `poevp schema` from the "
                           "params dataclasses. Cross-key checks: `poevp validate`.",
            "type": "object", "properties": props, "additionalProperties": False}


def schema_json() -> str:
    return json.dumps(scene_schema(), indent=2, sort_keys=False) + "\n"
