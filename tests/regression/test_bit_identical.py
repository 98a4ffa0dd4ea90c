"""Outputs and reports bit-identical to the recorded references (tests/regression/bit_identical.py).

A refactor must not change any output array or any physics number of the report. When the
physics or numerics change on purpose, the references are regenerated with a reason
(`python -m tests.regression.bit_identical --write "..."`) in the same commit.
"""

from __future__ import annotations

import json

import pytest

from tests.regression.bit_identical import CASES, REFERENCE, run_case


@pytest.mark.parametrize("name", list(CASES))
def test_outputs_are_bit_identical_to_the_references(tmp_path, name):
    ref = json.loads(REFERENCE.read_text())["cases"][name]
    got = run_case(name, tmp_path)
    assert set(got) == set(ref), sorted(set(got) ^ set(ref))
    changed = sorted(k for k in ref if ref[k] != got[k])
    assert not changed, f"{name}: {len(changed)} outputs changed, e.g. {changed[:5]}"
