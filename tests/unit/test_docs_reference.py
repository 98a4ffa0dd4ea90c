"""The scene-key reference (scene/reference.py) lists exactly the keys the scene loader accepts.

The accepted keys are found by asking the loader itself, not the params classes: a probe key
`zzz_probe` in every section (and sub-table) makes it refuse with its own list of known keys, a
[source] key under a kind that does not take it is refused as "not a key of kind", and every
key the page lists is set to a value of its type and must not be refused as unknown.
"""

from __future__ import annotations

import copy
import math
import re
import tomllib

import pytest

from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import build_spec
from poevp_optics.scene.reference import all_keys, markdown
from tests.conftest import SCENES

SMOKE = SCENES / "smoke" / "scene.toml"
RAW = tomllib.loads(SMOKE.read_text())
PROBE = "zzz_probe"
UNKNOWN = re.compile(r"unknown (?:key|section) \(known: ([^)]*)\)")


def _error(raw: dict) -> str:
    """The loader's one-line error for `raw` ('' when it accepts it), cross-key checks off."""
    try:
        build_spec(raw, SMOKE, cross_checks=False)
    except SceneError as e:
        return str(e)
    return ""


def _with(path: list[str], value, base: dict | None = None) -> dict:
    raw = copy.deepcopy(RAW if base is None else base)
    node = raw
    for p in path[:-1]:
        if not isinstance(node.get(p), dict):
            node[p] = {}
        node = node[p]
    node[path[-1]] = value
    return raw


def _known(path: list[str]) -> list[str] | None:
    """The keys the loader knows at `path` (a table), from its refusal of a probe key; None when
    `path` is not a table of keys."""
    m = UNKNOWN.search(_error(_with([*path, PROBE], 1)))
    return m.group(1).split(", ") if m else None


def accepted_keys() -> set[str]:
    """Every key path the loader accepts, table-section ids written `*`."""
    out: set[str] = set()

    def walk(path: list[str], shown: list[str]):
        for k in _known(path) or []:
            sub = _known([*path, k])
            if sub is None:
                out.add(".".join([*shown, k]))
            else:
                walk([*path, k], [*shown, k])

    for sec in _known([]):                      # the top level's refusal lists the sections
        if _known([sec]) is not None:
            walk([sec], [sec])
        else:                                   # a table of named entries: [sec.<id>]
            walk([sec, "entry"], [sec, "*"])
    return out


def listed_keys() -> set[str]:
    """The keys the generated page lists (section headings + table rows), ids written `*`."""
    out, sec = set(), None
    for line in markdown().splitlines():
        m = re.match(r"#{2,3} \[(.+)\]$", line)
        if m:
            sec = re.sub(r"<[^>]+>", "*", m.group(1))
            continue
        m = re.match(r"\| `([a-z0-9_]+)` \| (\w+)", line)
        if m and sec and m.group(2) != "table":
            out.add(f"{sec}.{m.group(1)}")
    return out


def test_reference_lists_every_accepted_key_and_no_other():
    accepted, listed = accepted_keys(), listed_keys()
    assert len(accepted) > 150                 # the probe found the sections' keys
    assert accepted - listed == set(), f"accepted by the loader, missing from the page: {accepted - listed}"
    assert listed - accepted == set(), f"listed on the page, refused by the loader: {listed - accepted}"


def _value(k):
    """A value of the key's type inside its bounds (choices: the first)."""
    if k.choices:
        return k.choices[0][0]
    d = k.default
    if isinstance(d, float) and math.isnan(d):
        lo = k.meta.get("min", k.meta.get("gt", 0.0))
        return float(lo) + 0.5 if "max" not in k.meta else (float(lo) + k.meta["max"]) / 2
    if isinstance(d, tuple) and "unset" in k.meta:
        return [0] * len(d)
    if d is __import__("dataclasses").MISSING:
        return "x" if k.tp is str else 1.0
    return list(d) if isinstance(d, tuple) else d


def test_every_listed_key_is_accepted_with_a_value_of_its_type():
    for k in all_keys():
        if k.is_table:
            continue
        path = k.key.replace("<id>", "entry").replace("<param>", "entry").split(".")
        base = RAW
        if path[0] == "source" and k.name != "kind":
            base = _with(["source", "kind"], k.kinds[0])
        err = _error(_with(path, _value(k), base))
        dotted = ".".join(path)
        refused = ("unknown key", "unknown section", "not a key of kind", "expected")
        assert not any(f"{dotted}: {r}" in err for r in refused), (k.key, err)


@pytest.mark.parametrize("kind", ["mitsuba", "exr_sequence", "ldr_highlight"])
def test_source_kinds_on_the_page_match_the_loader(kind):
    base = _with(["source", "kind"], kind)
    for k in all_keys():
        if k.section != "source" or k.name == "kind":
            continue
        refused = "not a key of kind" in _error(_with(["source", k.name], _value(k), base))
        assert refused == (kind not in k.kinds), (kind, k.name, k.kinds)


def test_every_key_has_type_unit_default_and_meaning():
    for k in all_keys():
        assert k.description.strip(), k.key
        assert k.unit, k.key
    page = markdown()
    assert "| `exposure_s` | float | s | `0.0166667` | (0, 100] |" in page
    assert "| `spp` | integer | - | `16` | [1, 1048576] |" in page


def test_registry_choices_carry_their_sources():
    from poevp_optics.control.masks import MASK_LAWS
    from poevp_optics.control.predictors import PREDICTORS

    page = markdown()
    for reg in (MASK_LAWS, PREDICTORS):
        for name in reg.names():
            line = f"- `{name}`: {reg.entry(name).source}"
            assert line.replace("\n", " ") in page, line


def test_top_level_description_is_accepted_and_other_top_keys_refused():
    assert _error(_with(["description"], "a scene")) == ""
    assert "unknown section" in _error(_with([PROBE], "x"))
    assert "| `description` | string |" in markdown()
