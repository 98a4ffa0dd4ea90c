"""core/registry.py: an entry may be None (its rule lives elsewhere); without an object,
`register` is a decorator."""

from poevp_optics.analysis.charts import DR_METHODS, chart_methods
from poevp_optics.control.timing_budget import COMPUTE_BUDGETS
from poevp_optics.core.registry import Registry


def test_none_is_an_entry_and_the_decorator_form_still_registers():
    reg = Registry("thing")
    assert reg.register("rule_elsewhere", None, source="s") is None
    assert "rule_elsewhere" in reg and reg["rule_elsewhere"] is None

    @reg.register("decorated", source="s")
    def f():
        return 1

    assert reg["decorated"] is f and reg.names() == ("rule_elsewhere", "decorated")


def test_the_registries_with_none_entries_hold_them():
    """These two were silently left out when None meant 'decorate'."""
    assert {"measured", "given"} <= set(COMPUTE_BUDGETS)
    assert "emva" in DR_METHODS and DR_METHODS["emva"] is None
    assert set(chart_methods()) == {"iso15739", "snr10"}
