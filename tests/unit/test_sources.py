"""[source] kinds (sources/): registry, time sampling, area resampling, units, boxes, and every
validation error as one line naming the file and the key."""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

from poevp_optics.camera.sensor import SENSOR_PRESETS
from poevp_optics.cli import main
from poevp_optics.core.io import write_exr
from poevp_optics.render.radiance import open_source
from poevp_optics.scene.load import load_scene
from poevp_optics.sources import spectra
from poevp_optics.sources.frames import AreaMap, Box, Clock
from poevp_optics.sources.kinds import SOURCES

CAMERA = """
[render]
resolution = [12, 16]
subframes = 3
seed = 3

[timing]
fps = 30.0
frames = 2
exposure_s = 0.02
dmd_window_s = 0.02

[relay]
psf = "delta"
"""


def _exr_scene(folder: Path, source: str, *, n: int = 4, shape=(12, 16), values=None, camera: str = CAMERA) -> Path:
    """An exr_sequence scene: n frames frames/f_J.exr (channel Y, value j + 1 unless `values`)."""
    (folder / "frames").mkdir(parents=True, exist_ok=True)
    for j in range(n):
        v = np.full(shape, float(j + 1), np.float32) if values is None else values[j]
        write_exr(folder / "frames" / f"f_{j}.exr", {"Y": v})
    (folder / "scene.toml").write_text("[source]\n" + textwrap.dedent(source) + camera)
    return folder


EXR = 'kind = "exr_sequence"\nframes = "frames/*.exr"\nunit = "photon_radiance"\nfps = 30.0\n'


def test_registry_names_the_three_kinds_with_references():
    assert set(SOURCES) == {"mitsuba", "exr_sequence", "ldr_highlight"}
    for name in SOURCES:
        assert SOURCES.entry(name).source, name
    assert load_scene(Path(__file__).parents[2] / "scenes" / "smoke").source.kind == "mitsuba"


# ---------------------------------------------------------------------------- time
def test_clock_nearest_linear_integrate():
    c = Clock.uniform(4, 10.0, 0.0)                    # frames at 0, .1, .2, .3 s
    assert c.taps_at(0.05, "nearest") == ((0, 1.0),)  # a tie goes to the earlier frame
    assert c.taps_at(0.051, "nearest") == ((1, 1.0),)
    assert c.taps_at(0.2, "linear") == ((2, 1.0),)
    (j0, w0), (j1, w1) = c.taps_at(0.125, "linear")
    assert (j0, j1) == (1, 2) and w0 == pytest.approx(0.75) and w1 == pytest.approx(0.25)
    assert c.taps_at(0.3, "linear") == ((3, 1.0),)
    taps = dict(c.taps_over(0.0, 0.2))                # frame 0 covers [-.05, .05): half inside
    assert taps[0] == pytest.approx(0.25) and taps[1] == pytest.approx(0.5) and taps[2] == pytest.approx(0.25)
    assert sum(taps.values()) == pytest.approx(1.0)
    assert c.span_s("linear") == (0.0, 0.3)
    assert c.span_s("nearest") == pytest.approx((-0.05, 0.35))
    t = Clock.from_times(np.array([0.0, 0.1, 0.4]))
    np.testing.assert_allclose(t.edges_s, [-0.05, 0.05, 0.25, 0.55])


# ---------------------------------------------------------------------------- space
def test_area_map_identity_is_an_exact_copy():
    rng = np.random.default_rng(1)
    img = rng.lognormal(30, 5, (7, 9)).astype(np.float32)
    m = AreaMap.build((7, 9), 0, (7, 9), 0)
    assert m.is_identity and np.array_equal(m.apply(img).astype(np.float32), img)
    m = AreaMap.build((11, 13), 2, (7, 9), 2)           # frames that hold the guard band
    assert m.is_identity and m.note() is None


def test_area_map_averages_blocks_and_replicates_edges():
    img = np.arange(8 * 12, dtype=np.float64).reshape(8, 12)
    half = AreaMap.build((8, 12), 0, (4, 6), 0).apply(img)
    np.testing.assert_allclose(half, img.reshape(4, 2, 6, 2).mean(axis=(1, 3)), rtol=1e-12)
    m = AreaMap.build((8, 12), 0, (8, 12), 3)            # guard band beyond the frames
    out = m.apply(img)
    assert out.shape == (14, 18)
    np.testing.assert_array_equal(out[3:-3, 3:-3], img)
    np.testing.assert_array_equal(out[0, 3:-3], img[0])  # edge replication
    np.testing.assert_array_equal(out[3:-3, -1], img[:, -1])
    assert m.replicated == (3, 3, 3, 3) and "edge replication" in m.note()
    flat = AreaMap.build((9, 15), 0, (4, 7), 1).apply(np.full((9, 15), 2.5))
    np.testing.assert_allclose(flat, 2.5, rtol=1e-12)   # a uniform field stays uniform
    assert m.box(Box(2, 1, 5, 4)) == (4, 5, 7, 8)
    assert AreaMap.build((8, 12), 0, (4, 6), 0).box(Box(1, 1, 5, 4)) == (0, 0, 2, 3)


# ---------------------------------------------------------------------------- units
def _response():
    qe = spectra.load_spectrum(SENSOR_PRESETS["IMX253"].qe, emissive=True)
    return qe * (spectra.WAVELENGTHS_NM * 1e-9) / (6.62607015e-34 * 299792458.0)


def test_radiance_w_is_weighted_by_the_sensor_response(tmp_path):
    d = _exr_scene(tmp_path / "s", EXR.replace("photon_radiance", "radiance_w") + 'spectrum = "cie:A"\n')
    src = open_source(load_scene(d).resolved.render, 0)
    spd = spectra.load_spectrum("cie:A", emissive=True)
    k = np.trapezoid(_response() * spd, spectra.WAVELENGTHS_NM) / np.trapezoid(spd, spectra.WAVELENGTHS_NM)
    assert src.factor == pytest.approx(k, rel=1e-12)
    ex = next(src.exposures(progress=False))
    np.testing.assert_allclose(ex.subframes[0], np.float32(1.0 * k), rtol=1e-7)


def test_relative_with_a_luminance_anchor(tmp_path):
    vals = [np.full((12, 16), 4.0, np.float32) for _ in range(4)]
    vals[1][5, 7] = 2.0
    d = _exr_scene(tmp_path / "s", EXR.replace("photon_radiance", "relative") + textwrap.dedent("""\
        luminance_cd_per_m2 = 100.0
        reference_pixel = [5, 7]
        reference_frame = 1
        spectrum = "cie:LED-B4"
        """), values=vals)
    src = open_source(load_scene(d).resolved.render, 0)
    spd = spectra.load_spectrum("cie:LED-B4", emissive=True)
    v = spectra.photopic_v()
    per_cd = np.trapezoid(_response() * spd, spectra.WAVELENGTHS_NM) / (683.002 * np.trapezoid(v * spd, spectra.WAVELENGTHS_NM))
    assert src.factor * 2.0 == pytest.approx(100.0 * per_cd, rel=1e-9)   # the anchor pixel reads 100 cd m-2


def test_exposures_carry_roi_text_and_motion_from_boxes(tmp_path):
    d = _exr_scene(tmp_path / "s", EXR + 'boxes = "boxes.csv"\nsubframes = "nearest"\n', n=4)
    (d / "boxes.csv").write_text("frame,x0,y0,x1,y1,text\n0,2,3,6,5,AB 12\n1,4,3,8,5,AB 12\n")
    exps = list(open_source(load_scene(d).resolved.render, 0).exposures(progress=False))
    assert exps[0].roi == (3, 2, 5, 8)            # union of frames 0 and 1 (nearest over 0 .. 20 ms)
    gt = exps[0].ground_truth
    assert gt["text"] == "AB 12" and gt["frames"] == ["f_0.exr", "f_1.exr"]
    assert gt["plate_velocity_px_per_s"] == pytest.approx([2 * 30.0, 0.0])
    assert exps[1].roi == (3, 4, 5, 8)            # frames 1 and 2 (33 .. 53 ms); only 1 has a box
    assert exps[1].ground_truth["plate_velocity_px_per_s"] is None
    assert exps[0].rel_error is None and not exps[0].variance.any()


# ---------------------------------------------------------------------------- errors
def _assert_one_line(capsys, rc, *parts):
    err = capsys.readouterr().err.strip()
    assert rc == 2, err
    assert len(err.splitlines()) == 1, err
    for p in parts:
        assert str(p) in err, (p, err)
    return err


EXR_BAD = [
    ("missing unit", EXR.replace('unit = "photon_radiance"\n', ""), "toml", "source.unit: required"),
    ("unknown unit", EXR.replace("photon_radiance", "nits"), "toml", "source.unit: must be one of"),
    ("no frames", EXR.replace("frames/*.exr", "none/*.exr"), "toml", "source.frames: no file matches"),
    ("missing fps", EXR.replace("fps = 30.0\n", ""), "toml", "source.fps: required"),
    ("fps and times", EXR + 'times_csv = "times.csv"\n', "toml", "source.fps: give either"),
    ("key of another kind", EXR + "e = 9.0\n", "toml", "source.e: not a key of kind = 'exr_sequence'"),
    ("radiance_w without spectrum", EXR.replace("photon_radiance", "radiance_w"), "toml", "source.spectrum: required"),
    ("relative without anchor", EXR.replace("photon_radiance", "relative"), "toml", "source.scale: unit = 'relative' needs"),
    ("anchor for absolute unit", EXR + "scale = 2.0\n", "toml", "source.scale: does not apply"),
    ("unknown spectrum", EXR.replace("photon_radiance", "radiance_w") + 'spectrum = "cie:Q"\n', "toml", "source.spectrum:"),
    ("missing boxes file", EXR + 'boxes = "nope.csv"\n', "toml", "source.boxes: file not found"),
    ("unknown subframes", EXR + 'subframes = "cubic"\n', "toml", "source.subframes: must be one of"),
    ("too few frames", EXR.replace("fps = 30.0", "fps = 120.0"), "toml", "source.frames: the 4 frames cover"),
    ("mitsuba section", EXR + "[motion.car]\nkind = \"static\"\n", "toml", "motion.car: source.kind = 'exr_sequence'"),
    ("render.xml", EXR, "xml", "render.xml: source.kind = 'exr_sequence'"),
    ("source keys for mitsuba", 'kind = "mitsuba"\nfps = 30.0\n', "toml", "source.fps: not a key of kind = 'mitsuba'"),
]


@pytest.mark.parametrize("desc,source,where,expected", EXR_BAD, ids=[b[0] for b in EXR_BAD])
def test_bad_exr_source_is_one_line_naming_file_and_key(tmp_path, capsys, desc, source, where, expected):
    cam = CAMERA.replace("[render]", '[render]\nxml = "scene.xml"') if where == "xml" else CAMERA
    d = _exr_scene(tmp_path / "bad", source, camera=cam)
    _assert_one_line(capsys, main(["validate", str(d)]), d / "scene.toml", expected)


def _write_raw_exr(path: Path, arr: np.ndarray, channel: str = "Y") -> None:
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {channel: arr.astype(np.float32)}) as f:
        f.write(str(path))


@pytest.mark.parametrize("desc,edit,expected", [
    ("NaN", lambda a: a.__setitem__((2, 3), np.nan) or a, "source.frames: 1 NaN/Inf values"),
    ("Inf", lambda a: a.__setitem__((2, 3), np.inf) or a, "source.frames: 1 NaN/Inf values"),
    ("negative", lambda a: a.__setitem__((0, 0), -1.0) or a, "source.frames: 1 negative values"),
    ("size", lambda a: a[:, :-1], "source.frames: 12x15 px"),
], ids=["NaN", "Inf", "negative", "size"])
def test_bad_frame_names_the_frame_file(tmp_path, capsys, desc, edit, expected):
    d = _exr_scene(tmp_path / "bad", EXR)
    f = d / "frames" / "f_1.exr"
    _write_raw_exr(f, edit(np.ones((12, 16), np.float32)))
    _assert_one_line(capsys, main(["validate", str(d)]), f, expected)
    out = tmp_path / "out"
    _assert_one_line(capsys, main(["render", str(d), "--out", str(out), "--quiet"]), f, expected)
    assert not out.exists()


def test_missing_channel_and_unreadable_frame(tmp_path, capsys):
    d = _exr_scene(tmp_path / "a", EXR + 'channel = "R"\n')
    _assert_one_line(capsys, main(["validate", str(d)]), d / "frames" / "f_0.exr", "source.channel: no channel 'R'")
    d = _exr_scene(tmp_path / "b", EXR)
    (d / "frames" / "f_2.exr").write_text("not an exr")
    _assert_one_line(capsys, main(["validate", str(d)]), d / "frames" / "f_2.exr", "source.frames: not an OpenEXR")


@pytest.mark.parametrize("desc,csv,expected", [
    ("frame out of range", "frame,x0,y0,x1,y1,text\n9,0,0,2,2,A\n", "source.boxes: frame 9 is not one of the 4"),
    ("empty box", "frame,x0,y0,x1,y1\n0,5,0,2,2\n", "source.boxes: empty box"),
    ("no header", "0,0,0,2,2\n", "source.boxes: the header"),
    ("not a number", "frame,x0,y0,x1,y1\n0,a,0,2,2\n", "source.boxes: column x0: not a number"),
    ("outside", "frame,x0,y0,x1,y1\n0,40,0,50,2\n", "source.boxes: box x0=40"),
])
def test_bad_boxes_csv_names_the_csv(tmp_path, capsys, desc, csv, expected):
    d = _exr_scene(tmp_path / "bad", EXR + 'boxes = "boxes.csv"\n')
    (d / "boxes.csv").write_text(csv)
    _assert_one_line(capsys, main(["validate", str(d)]), d / "boxes.csv", expected)


def test_bad_times_csv_and_aspect(tmp_path, capsys):
    src = EXR.replace("fps = 30.0\n", 'times_csv = "times.csv"\n')
    d = _exr_scene(tmp_path / "t", src)
    (d / "times.csv").write_text("file,t_s\nf_0.exr,0.0\nf_1.exr,0.05\nf_2.exr,0.04\nf_3.exr,0.1\n")
    _assert_one_line(capsys, main(["validate", str(d)]), d / "times.csv", "source.times_csv: times must increase")
    (d / "times.csv").write_text("file,t_s\nf_0.exr,0.0\nf_1.exr,0.05\n")
    _assert_one_line(capsys, main(["validate", str(d)]), d / "times.csv", "source.times_csv: no row for frame file 'f_2.exr'")
    d = _exr_scene(tmp_path / "a", EXR, shape=(12, 24))
    _assert_one_line(capsys, main(["validate", str(d)]), d / "scene.toml", "source.frames: the frames' field is 12x24")


# ---------------------------------------------------------------------------- ldr_highlight
LDR = textwrap.dedent("""\
    kind = "ldr_highlight"
    frames = "ldr/*.png"
    e = 9.0
    r_px = 50.0
    box = [4.0, 3.0, 10.0, 7.0]
    scale = 1e16
    fps = 30.0
    subframes = "nearest"
    """)


def _ldr_scene(folder: Path, source: str, n: int = 3) -> Path:
    (folder / "ldr").mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(5)
    for j in range(n):
        cv2.imwrite(str(folder / "ldr" / f"o_{j}.png"), rng.integers(0, 256, (12, 16), dtype=np.uint8))
    (folder / "scene.toml").write_text("[source]\n" + source + CAMERA)
    return folder


LDR_BAD = [
    ("missing e", LDR.replace("e = 9.0\n", ""), "source.e: required"),
    ("missing r_px", LDR.replace("r_px = 50.0\n", ""), "source.r_px: required"),
    ("negative e", LDR.replace("e = 9.0", "e = -1.0"), "source.e: must be >= 0"),
    ("box and boxes", LDR + 'boxes = "b.csv"\n', "source.box: give one of"),
    ("bad box", LDR.replace("box = [4.0, 3.0, 10.0, 7.0]", "box = [4.0, 3.0, 1.0, 7.0]"), "source.box: expected"),
    ("no anchor", LDR.replace("scale = 1e16\n", ""), "source.scale: give one absolute anchor"),
    ("luminance without spectrum", LDR.replace("scale = 1e16", "luminance_cd_per_m2 = 50.0"), "source.spectrum: required"),
    ("gamma without transfer", LDR + "gamma = 2.4\n", "source.gamma: only used with transfer = 'gamma'"),
    ("unit of exr", LDR + 'unit = "relative"\n', "source.unit: not a key of kind = 'ldr_highlight'"),
    ("frames and video", LDR + 'video = "v.avi"\n', "source.frames: give one of"),
    ("unknown rule", LDR + 'radius_rule = "fwhm"\n', "source.radius_rule: must be one of"),
]


@pytest.mark.parametrize("desc,source,expected", LDR_BAD, ids=[b[0] for b in LDR_BAD])
def test_bad_ldr_source_is_one_line_naming_file_and_key(tmp_path, capsys, desc, source, expected):
    d = _ldr_scene(tmp_path / "bad", source)
    _assert_one_line(capsys, main(["validate", str(d)]), d / "scene.toml", expected)


def test_unreadable_and_mismatched_ldr_frames(tmp_path, capsys):
    d = _ldr_scene(tmp_path / "a", LDR)
    (d / "ldr" / "o_1.png").write_text("not a png")
    _assert_one_line(capsys, main(["validate", str(d)]), d / "ldr" / "o_1.png", "source.frames: not an image")
    d = _ldr_scene(tmp_path / "b", LDR)
    cv2.imwrite(str(d / "ldr" / "o_1.png"), np.zeros((12, 15), np.uint8))
    _assert_one_line(capsys, main(["validate", str(d)]), d / "ldr" / "o_1.png", "source.frames: 12x15 px")


def test_ldr_video_matches_its_frames(tmp_path):
    """A lossless video (FFV1) of the PNG frames gives the same radiance as the frames."""
    d = _ldr_scene(tmp_path / "v", LDR)
    frames = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in sorted((d / "ldr").glob("*.png"))]
    w = cv2.VideoWriter(str(d / "clip.avi"), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (16, 12), True)
    for f in frames:
        w.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    w.release()
    a = [e.subframes[0] for e in open_source(load_scene(d).resolved.render, 0).exposures(progress=False)]
    (d / "scene.toml").write_text((d / "scene.toml").read_text().replace('frames = "ldr/*.png"', 'video = "clip.avi"'))
    src = open_source(load_scene(d).resolved.render, 0)
    b = [e.subframes[0] for e in src.exposures(progress=False)]
    assert src.plan.reason.startswith("video clip.avi (3 frames)")
    for x, y in zip(a, b):
        np.testing.assert_allclose(y, x, rtol=1e-6)


def test_frame_source_scene_needs_no_xml_and_lists_its_files(tmp_path):
    from poevp_optics.apps.sweep.bundle import scene_inputs

    d = _exr_scene(tmp_path / "s", EXR + 'boxes = "boxes.csv"\n')
    (d / "boxes.csv").write_text("frame,x0,y0,x1,y1\n0,1,1,3,3\n")
    spec = load_scene(d)
    assert spec.xml_path is None and not spec.geometry_static and not spec.is_static
    names = {Path(r.source).name for r in scene_inputs(spec)}
    assert {"scene.toml", "boxes.csv", "f_0.exr", "f_3.exr"} <= names
    assert math.isnan(spec.source.scale)


def test_jpeg_frames_and_gamma_transfer(tmp_path):
    """JPEG frames by glob; transfer = 'gamma': O = (V / 255)^gamma; e = 0 leaves O unchanged."""
    d = tmp_path / "j"
    (d / "ldr").mkdir(parents=True)
    for j in range(3):
        cv2.imwrite(str(d / "ldr" / f"o_{j}.jpg"), np.full((12, 16, 3), 200, np.uint8))
    src = LDR.replace("ldr/*.png", "ldr/*.jpg").replace("e = 9.0", "e = 0.0") + 'transfer = "gamma"\ngamma = 2.2\n'
    (d / "scene.toml").write_text("[source]\n" + src + CAMERA)
    ex = next(open_source(load_scene(d).resolved.render, 0).exposures(progress=False))
    rgb = cv2.imread(str(d / "ldr" / "o_0.jpg"))[..., ::-1].astype(float)   # JPEG may move a code
    np.testing.assert_allclose(ex.subframes[0], 1e16 * ((rgb / 255.0) ** 2.2) @ [0.2126, 0.7152, 0.0722], rtol=1e-6)
    assert abs(rgb.mean() - 200) <= 1


def test_compare_runs_every_predictor_on_one_read_of_a_frame_source(tmp_path):
    """`poevp compare` opens the scene's [source] (here the LDR demo, 4 frames): the oracle row is
    the plain render run's oracle, and every run's frames carry the source's ground truth."""
    import json

    from poevp_optics.apps.run.compare import compare
    from poevp_optics.apps.run.render_run import run_render

    spec = load_scene(Path(__file__).parents[2] / "scenes" / "ldr_highlight_demo", ["timing.frames=4"])
    rows = {r["predictor"]: r for r in compare(spec, ["oracle", "hold"], ["open"], tmp_path / "c", progress=False)}
    ref = run_render(spec, tmp_path / "r", progress=False)["metrics"]["saturated_fraction_roi"]
    assert rows["oracle"]["sat_loop_after_init"] == ref["encoded_after_init"]
    assert rows["oracle"]["sat_ldr"] == ref["ldr"] and rows["hold"]["sat_ldr"] == ref["ldr"]
    for tag in ("oracle", "hold_open"):
        frames = json.loads((tmp_path / "c" / tag / "report.json").read_text())["per_frame"]
        assert [f["ground_truth"]["text"] for f in frames] == ["JN F9H28"] * 4
