"""`poevp schema`: a JSON Schema (draft 2020-12) of scene.toml that accepts every shipped scene
and refuses what the loader refuses (unknown keys, wrong types, out-of-range values, choices
outside a registry, a [source] key its kind does not take)."""

from __future__ import annotations

import copy
import json
import tomllib

import jsonschema
import pytest

from poevp_optics.cli import main
from poevp_optics.core.exceptions import SceneError
from poevp_optics.scene.load import build_spec
from tests.conftest import SCENES

SHIPPED = sorted(SCENES.glob("*/scene.toml"))
SMOKE = SCENES / "smoke" / "scene.toml"


@pytest.fixture(scope="module")
def schema(tmp_path_factory):
    out = tmp_path_factory.mktemp("schema") / "scene.schema.json"
    assert main(["schema", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    jsonschema.Draft202012Validator.check_schema(doc)
    return doc


def _errors(schema, raw):
    return list(jsonschema.Draft202012Validator(schema).iter_errors(raw))


def test_schema_is_draft_2020_12(schema):
    assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
    assert schema["additionalProperties"] is False


@pytest.mark.parametrize("path", SHIPPED, ids=[p.parent.name for p in SHIPPED])
def test_every_shipped_scene_validates(schema, path):
    assert len(SHIPPED) >= 15
    assert _errors(schema, tomllib.loads(path.read_text())) == []


def _mutate(path: list[str], value) -> dict:
    raw = tomllib.loads(SMOKE.read_text())
    node = raw
    for p in path[:-1]:
        node = node.setdefault(p, {})
    node[path[-1]] = value
    return raw


BAD = {
    "unknown key": (["render", "sppp"], 16),
    "unknown section": (["renderer"], {}),
    "unknown key in a table entry": (["motion", "plate", "velocity"], [0.0, 0.0, 1.0]),
    "unknown key in a sub-table": (["dmd", "registration", "angle_deg"], 1.0),
    "wrong type (string for integer)": (["render", "spp"], "16"),
    "wrong type (float for integer)": (["timing", "frames"], 2.5),
    "wrong type (number for boolean)": (["sensor", "noise"], 1),
    "wrong array length": (["render", "resolution"], [48, 64, 3]),
    "below minimum": (["render", "spp"], 0),
    "at an exclusive bound": (["dmd", "contrast_ratio"], 1.0),
    "not a registered choice": (["mask", "law"], "threshold"),
    "a key of another [source] kind": (["source"], {"kind": "exr_sequence", "video": "v.mp4"}),
    "a [source] key under mitsuba": (["source"], {"frames": "*.exr"}),
}


@pytest.mark.parametrize("case", BAD, ids=list(BAD))
def test_schema_refuses_what_the_loader_refuses(schema, case):
    path, value = BAD[case]
    raw = _mutate(path, value)
    assert _errors(schema, raw), case
    with pytest.raises(SceneError):                    # the loader agrees (its one-line error)
        build_spec(copy.deepcopy(raw), SMOKE)


def test_schema_carries_units_defaults_and_registry_choices(schema):
    from poevp_optics.control.masks import MASK_LAWS

    exp = schema["properties"]["timing"]["properties"]["exposure_s"]
    assert exp["type"] == "number" and exp["exclusiveMinimum"] == 0 and "[s]" in exp["description"]
    law = schema["properties"]["mask"]["properties"]["law"]
    assert law["enum"] == list(MASK_LAWS.names())
    assert schema["properties"]["spectra"]["additionalProperties"]["required"] == ["kind", "source"]
    bits = schema["properties"]["sensor"]["properties"]["bits"]     # -1: the preset's
    assert _errors({"type": "object", "properties": {"b": bits}}, {"b": -1}) == []
    assert _errors({"type": "object", "properties": {"b": bits}}, {"b": 0})


def test_schema_to_stdout(capsys):
    assert main(["schema"]) == 0
    assert json.loads(capsys.readouterr().out)["title"] == "poevp_optics scene.toml"
