"""benchmarks/loop_alpr.py: which plate-frames it reads, how it counts them and its verdict, on
hand-made report records; the verdict's boundary from Wilson's interval solved here as the root
of its quadratic (independent of analysis/statistics.py's closed form)."""

from __future__ import annotations

import math

from benchmarks.loop_alpr import alt_text, eligible, tally, verdict

Z95 = 1.959963984540054   # Phi^-1(0.975)


def _plate(ident, y0, h, in_view=True):
    return {"id": ident, "in_view": in_view, "box": [y0, 10, y0 + h, 60] if in_view else None,
            "height_px": h if in_view else None}


def test_eligible_skips_init_frames_small_and_out_of_view_plates():
    per_frame = [
        {"index": 0, "init": True, "plates": [_plate("a", 5, 30)]},            # white initialisation frame
        {"index": 1, "init": True, "plates": [_plate("a", 5, 31)]},
        {"index": 2, "plates": [_plate("a", 5, 19), _plate("b", 40, 25)]},     # a: 19 px < 20
        {"index": 3, "plates": [_plate("a", 5, 20), _plate("b", 40, 0, in_view=False)]},
        {"index": 4, "plates": []},
    ]
    assert eligible(per_frame, 20) == [(2, "b", (40, 10, 65, 60)), (3, "a", (5, 10, 25, 60))]
    assert eligible(per_frame, 26) == []


def test_eligible_single_region_of_interest():
    per_frame = [{"index": 0, "init": True, "roi": [0, 0, 40, 90]},
                 {"index": 1, "roi": [3, 4, 24, 90]},        # 21 px
                 {"index": 2, "roi": [3, 4, 22, 90]},        # 19 px
                 {"index": 3, "roi": None}]
    assert eligible(per_frame, 20) == [(1, "plate", (3, 4, 24, 90))]


def test_tally_counts_reads_per_plate():
    assert tally([("a", True), ("a", False), ("b", False), ("a", True)]) == {"a": (2, 3), "b": (0, 1)}


def _wilson_low(k, n, z=Z95):
    """Lower root of (k/n - p)^2 = z^2 p (1 - p) / n."""
    a = 1 + z * z / n
    b = -(2 * k / n + z * z / n)
    c = (k / n) ** 2
    return (-b - math.sqrt(b * b - 4 * a * c)) / (2 * a)


def test_verdict_boundary_is_the_lower_end_of_flows_interval():
    low = _wilson_low(8, 10)                 # 8/10: 0.4902
    assert 0.40 < low < 0.50                 # so 5/10 sits above it and 4/10 below
    assert verdict((5, 10), (8, 10)) == (True, False)
    assert verdict((4, 10), (8, 10)) == (False, False)
    assert verdict((9, 10), (8, 10)) == (True, True)
    assert verdict((8, 10), (8, 10)) == (True, False)
    assert verdict((3, 3), (2, 3)) == (True, True)
    assert verdict((0, 0), (2, 3)) == (True, False)     # nothing counted: no comparison


def test_alt_text_keeps_layout_and_changes_every_character():
    assert alt_text("JN F9H28", 0) == "JN F9H28"
    assert alt_text("JN F9H28", 1) == "TX N2R51"    # letters +7 in A-Z less I, O, Q; digits +3
    for text in ("B CN 204", "OB 180 I", "NR 17 RA"):
        alt = alt_text(text, 1)
        assert len(alt) == len(text) and not set(alt) & set("IOQ")
        assert all((a == " ") == (t == " ") and (a != t or t == " ") for a, t in zip(alt, text))


def test_cells_pool_text_sets_per_plate_and_gain_and_name_small_plates():
    from benchmarks.loop_alpr import cells

    def run(text_set, gain, reads):
        return {"scene": "s", "gain": gain, "text_set": text_set,
                "labels": {"a": f"A{text_set}", "b": f"B{text_set}", "c": f"C{text_set}"},
                "heights": {"a": (20, 30), "b": (12, 14)},          # c: never in view
                "reads": reads}

    r0 = run(0, 1.0, {"flow": [(2, "a", True, "A0"), (3, "a", False, "-")],
                      "track_net": [(2, "a", True, "A0"), (3, "a", True, "A0")]})
    r1 = run(1, 1.0, {"flow": [(2, "a", False, "-")], "track_net": [(2, "a", True, "A1")]})
    r2 = run(0, 10.0, {"flow": [(4, "a", True, "A0")], "track_net": [(4, "a", False, "-")]})
    rows, small = cells([r0, r1, r2], ["flow", "track_net"])
    assert [r[:5] for r in rows] == [["s", "a", "1x", "`A0`, `A1`", "20-30"], ["s", "a", "10x", "`A0`", "20-30"]]
    assert rows[0][5].startswith("1/3 ") and rows[0][6].startswith("3/3 ")
    assert rows[0][7] == "yes, higher"
    assert rows[1][5].startswith("1/1 ") and rows[1][6].startswith("0/1 ")
    assert rows[1][7] == "**no**"          # 0/1 below flow's 1/1 interval's lower end (0.21)
    assert small == ["s / b at 1x: under the minimum height in every loop frame (12-14 px)",
                     "s / c at 1x: out of view in every loop frame",
                     "s / b at 10x: under the minimum height in every loop frame (12-14 px)",
                     "s / c at 10x: out of view in every loop frame"]
