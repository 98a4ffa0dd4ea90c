"""Scene bundles (issue 21): what a point reads, how it reaches a worker, how its outputs return.

A "worker" here is `materialize` run with another folder and another package assets/ (an
explicit argument, as a worker whose installed package differs would have); the cluster test
(tests/regression/test_sweep_cluster.py) runs the same code on real `dask worker` processes.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from poevp_optics import __version__
from poevp_optics.apps.sweep.bundle import (InputMismatch, check_same_inputs, make_bundle, make_plan, map_paths,
                                      materialize, pack_folder, scene_inputs, unpack_archive, with_hashes)
from poevp_optics.apps.sweep.cluster import software_versions, version_mismatch
from poevp_optics.apps.sweep.sweep import PointTask, run_point
from poevp_optics.core.paths import ASSETS_DIR
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES


def _smoke_toml() -> str:
    """smoke's scene.toml without its last section, the pinned [predictor] (the fixtures name their own)."""
    toml = (SCENES / "smoke" / "scene.toml").read_text()
    return toml[:toml.rindex("[predictor]")]


@pytest.fixture
def client_scene(tmp_path):
    """smoke, rearranged as users arrange scenes: the XML in a sibling folder (`../shared`),
    weights beside the TOML, a lamp spectrum named by absolute path, and the plate texture and
    the sensor's QE table from the package's assets/."""
    scenes = tmp_path / "client" / "scenes"
    (scenes / "shared").mkdir(parents=True)
    (scenes / "mine" / "w").mkdir(parents=True)
    shutil.copy(SCENES / "smoke" / "scene.xml", scenes / "shared" / "scene.xml")
    shutil.copy(ASSETS_DIR / "predictor" / "dmvfn_lite.safetensors", scenes / "mine" / "w" / "lite.safetensors")
    lamp = tmp_path / "elsewhere" / "led.csv"
    lamp.parent.mkdir()
    wl = np.arange(380, 781, 5)
    lamp.write_text("wavelength_nm,value\n" + "".join(f"{w},{1 + 0.001 * (w - 380)}\n" for w in wl))
    toml = _smoke_toml()
    toml = toml.replace('source = "cie:LED-B4"', f'source = "file:{lamp}"')
    toml = toml.replace("[render]\n", '[render]\nxml = "../shared/scene.xml"\n')
    toml += '\n[predictor]\nname = "dmvfn_lite"\nweights = "w/lite.safetensors"\nresolution = [48, 64]\n'
    (scenes / "mine" / "scene.toml").write_text(toml)
    return scenes / "mine" / "scene.toml", lamp


def _assert_worker_renders_like_the_client(tmp_path, client_spec, worker_spec, path_map):
    """The client's and the worker's specs render the same outputs once the worker's report has
    its paths mapped back to the client's (as run_point does)."""
    from poevp_optics.apps.run.render_run import run_render
    from tests.regression.bit_identical import hash_outputs

    outs = {}
    for name, sp in (("client", client_spec), ("worker", worker_spec)):
        outs[name] = tmp_path / "out" / name
        outs[name].mkdir(parents=True)
        run_render(sp, outs[name], progress=False)
    report = json.loads((outs["worker"] / "report.json").read_text())
    (outs["worker"] / "report.json").write_text(json.dumps(map_paths(report, path_map)))
    assert hash_outputs(outs["client"]) == hash_outputs(outs["worker"])


def test_inputs_are_listed_with_how_a_worker_finds_them(client_scene):
    toml, lamp = client_scene
    refs = {r.key: r for r in with_hashes(scene_inputs(load_scene(toml)))}
    scenes = toml.parent.parent
    assert refs["scene file"].kind == "scene" and refs["render.xml"].place == str(scenes / "shared" / "scene.xml")
    assert refs["predictor.weights"].kind == "scene"
    assert refs["spectra.lamp.source"].kind == "absolute" and refs["spectra.lamp.source"].place == str(lamp)
    plate = next(r for k, r in refs.items() if "plate_texture" in k)
    # found in assets/, looked for first beside the XML: a worker lacking it gets it there
    assert plate.kind == "assets" and plate.asset == "plates/plate_B4713.png"
    assert plate.place == str(scenes / "shared" / "plates" / "plate_B4713.png") and not plate.override
    # spectrum tables are read from assets/ only: a worker lacking it gets the key pointed at a copy
    qe = refs["sensor.qe"]
    assert qe.kind == "assets" and not qe.place and qe.override == "sensor.qe=file:{}"
    assert all(len(r.sha256) == 64 for r in refs.values())
    assert make_plan("bundle", toml, list(refs.values())).root == str(scenes)


def test_bundle_unpacks_into_a_mirror_that_loads_with_the_same_inputs(client_scene, tmp_path):
    toml, lamp = client_scene
    refs = with_hashes(scene_inputs(load_scene(toml)))
    plan = make_plan("bundle", toml, refs)
    bundle = make_bundle(plan, refs)
    assert bundle.files == 5                    # TOML, XML, weights, plate, QE table (not the absolute lamp)
    # a worker whose package assets/ lacks the plate and the QE table
    bare = tmp_path / "worker_assets"
    bare.mkdir()
    work = tmp_path / "worker" / "point"
    work.mkdir(parents=True)
    m = materialize(plan, refs, bundle.data, work, assets_dir=bare)
    assert m.scene == str(work / "scenes" / "mine" / "scene.toml")
    assert (work / "scenes" / "shared" / "plates" / "plate_B4713.png").is_file()
    assert len(m.overrides) == 1 and m.overrides[0].startswith("sensor.qe=")
    spec = load_scene(m.scene, list(m.overrides))
    check_same_inputs(refs, spec, m.path_map)  # the same bytes under the same keys
    assert map_paths(str(spec.toml_path), m.path_map) == str(toml)
    assert map_paths({"a": [f"see {spec.xml_path}"]}, m.path_map) == {"a": [f"see {toml.parent.parent}/shared/scene.xml"]}
    # the mirror with its placed asset and overridden key renders what the client renders
    _assert_worker_renders_like_the_client(tmp_path, load_scene(toml), spec, m.path_map)
    # a worker with the same package assets reads its own copies: nothing placed, no override
    work2 = tmp_path / "worker" / "point2"
    work2.mkdir()
    m2 = materialize(plan, refs, bundle.data, work2)
    assert m2.overrides == () and not (work2 / "scenes" / "shared" / "plates").exists()
    check_same_inputs(refs, load_scene(m2.scene), m2.path_map)
    # ... and a lookup that resolves to other bytes there is caught after loading
    (work2 / "scenes" / "shared" / "plates").mkdir()
    (work2 / "scenes" / "shared" / "plates" / "plate_B4713.png").write_bytes(b"not the client's plate")
    with pytest.raises(InputMismatch, match="plate_texture.*sha256"):
        check_same_inputs(refs, load_scene(m2.scene), m2.path_map)


def test_a_worker_that_sees_other_bytes_is_refused(client_scene, tmp_path):
    toml, lamp = client_scene
    refs = with_hashes(scene_inputs(load_scene(toml)))
    bundle = make_bundle(make_plan("bundle", toml, refs), refs)
    shared = make_plan("shared", toml, refs)
    (tmp_path / "w1").mkdir()
    m = materialize(shared, refs, None, tmp_path / "w1")      # the same file system: fine
    assert m.scene == str(toml) and m.overrides == ()
    # a file named by absolute path differs on the worker: one line naming key, path and hashes
    lamp.write_text(lamp.read_text() + "780,1.5\n")
    for plan, data in ((make_plan("bundle", toml, refs), bundle.data), (shared, None)):
        work = tmp_path / f"w-{plan.mode}"
        work.mkdir()
        with pytest.raises(InputMismatch, match=r"spectra\.lamp\.source: .*led\.csv holds other bytes there"):
            materialize(plan, refs, data, work)
    # with --shared-fs, a scene file that differs is refused as well
    (toml.parent.parent / "shared" / "scene.xml").write_text("<scene/>")
    (tmp_path / "w3").mkdir()
    with pytest.raises(InputMismatch, match="render.xml"):
        materialize(shared, [r for r in refs if r.key != "spectra.lamp.source"], None, tmp_path / "w3")


def test_point_archive_round_trip_and_unsafe_names(tmp_path):
    import io
    import zipfile

    src = tmp_path / "src"
    (src / "radiance").mkdir(parents=True)
    (src / "radiance" / "frame_0000.exr").write_bytes(b"\x76\x2f\x31\x01" + bytes(range(256)))
    (src / "report.json").write_text('{"a": 1}\n')
    dest = tmp_path / "dest"
    dest.mkdir()
    assert unpack_archive(pack_folder(src), dest) == 2
    assert {str(p.relative_to(dest)): p.read_bytes() for p in dest.rglob("*") if p.is_file()} == \
           {str(p.relative_to(src)): p.read_bytes() for p in src.rglob("*") if p.is_file()}
    for bad in ("../escape.txt", "/abs.txt", "a/../../b.txt"):
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as zf:
            zf.writestr(bad, b"x")
        with pytest.raises(ValueError, match="not a plain relative file name"):
            unpack_archive(buf.getvalue(), dest)
    assert not (tmp_path / "escape.txt").exists()


def test_a_point_refuses_a_client_with_other_software(client_scene):
    """run_point compares the client's versions (sent with the task) with its own process's."""
    toml, _ = client_scene
    refs = tuple(with_hashes(scene_inputs(load_scene(toml))))
    mine = software_versions()
    assert mine["poevp_optics"] == __version__
    client = {**mine, "poevp_optics": __version__ + ".other"}
    assert version_mismatch(client, mine) == f"poevp_optics {__version__} there, {__version__}.other here"
    task = PointTask(("render.spp=4",), "render", 1, make_plan("shared", toml, list(refs)), refs, client)
    res = run_point(task)
    assert set(res) == {"refused"}
    assert res["refused"] == (f"this process: poevp_optics {__version__} there, {__version__}.other here; "
                              "install the same software on every worker")


def test_a_point_whose_files_changed_is_refused_not_failed(client_scene):
    """A point verifies its inputs against the client's hashes before running: a file edited
    since the sweep hashed it is a refusal (the sweep stops with this line), not a failed row."""
    toml, lamp = client_scene
    refs = tuple(with_hashes(scene_inputs(load_scene(toml))))
    lamp.write_text(lamp.read_text().replace("780,", "780.0,"))
    task = PointTask(("render.spp=4",), "render", 1, make_plan("shared", toml, list(refs)), refs)
    res = run_point(task)
    assert set(res) == {"refused"}
    assert res["refused"].startswith(f"this process: spectra.lamp.source: {lamp} holds other bytes there (sha256 ")


# ---------------------------------------------------------------------------- the new layout's inputs
LAMP_SHEET_TOML = """
[spectra.lamp]
kind = "intensity"
source = "cie:LED-B4"
intensity_cd = 20000.0
distribution = "file:lamps/low_beam.ldt"

[sheeting.wall_sheeting]
source = "file:tables/sheet.csv"

[relay]
psf = "measured"
measured_file = "psf/relay_example_psf.png"

[predictor]
name = "dmvfn_lite"
resolution = [48, 64]
"""


@pytest.fixture
def lamp_sheet_scene(tmp_path):
    """smoke with a photometric low beam (an EULUMDAT file of assets/), its wall covered in
    retroreflective sheeting from a CSV table beside the TOML, the measured PSF of assets/ and
    the lite predictor's shipped weights: every kind of file the layout's loaders read
    (render/materials/, camera/relay.py, control/predictors/dmvfn.py)."""
    folder = tmp_path / "client" / "lampy"
    (folder / "tables").mkdir(parents=True)
    xml = (SCENES / "smoke" / "scene.xml").read_text()
    spot = xml[xml.index('    <emitter type="spot"'):xml.index("</emitter>") + len("</emitter>")]
    xml = xml.replace(spot, """    <emitter type="photometric" id="lamp">
        <transform name="to_world"><lookat origin="0, 0.2, 0" target="0, 0, 5" up="0, 1, 0"/></transform>
        <spectrum name="intensity" value="$lamp"/>
        <string name="distribution" value="$lamp_distribution"/>
    </emitter>""")
    xml = xml.replace('<default name="lamp" value="1"/>', '<default name="lamp" value="1"/>\n'
                      '    <default name="lamp_distribution" value=""/>\n'
                      '    <default name="wall_sheeting" value="astm_d4956:III"/>')
    xml = xml.replace('<bsdf type="diffuse"><spectrum name="reflectance" value="$wall"/></bsdf>',
                      '<bsdf type="retroreflective"><string name="sheeting" value="$wall_sheeting"/>'
                      '<spectrum name="reflectance" value="$wall"/></bsdf>')
    (folder / "scene.xml").write_text(xml)
    # ASTM D4956-01 Table 4, Type III white (cd lx-1 m-2), as tests/physics/test_retroreflection.py
    ra = {4.0: {0.1: 300.0, 0.2: 250.0, 0.5: 95.0}, 30.0: {0.1: 180.0, 0.2: 150.0, 0.5: 65.0}}
    (folder / "tables" / "sheet.csv").write_text(
        "# efficiency = 0.3\nalpha_deg,beta_deg,ra_cd_per_lx_m2\n"
        + "".join(f"{a},{b},{v}\n" for b, row in ra.items() for a, v in row.items()))
    toml = _smoke_toml()
    lamp = toml[toml.index("[spectra.lamp]"):toml.index("[spectra.white]")]
    (folder / "scene.toml").write_text(toml.replace(lamp, "") + LAMP_SHEET_TOML)
    return folder / "scene.toml"


def _opened_by_python(fn):
    """Files Python opens while `fn()` runs (the `open` audit event: io.open, os.open, numpy,
    photompy, eulumdat-py; not native readers such as OpenCV, Mitsuba's bitmap or safetensors)."""
    import sys

    seen: list[str] = []
    _AUDIT["sink"] = seen
    if not _AUDIT["installed"]:
        def hook(event, args):
            sink = _AUDIT["sink"]
            if sink is not None and event == "open" and isinstance(args[0], (str, bytes)) and args[0]:
                sink.append(os.fsdecode(args[0]))

        sys.addaudithook(hook)                  # hooks cannot be removed: it records only while set
        _AUDIT["installed"] = True
    try:
        fn()
    finally:
        _AUDIT["sink"] = None
    return {str(Path(p).resolve()) for p in seen if Path(p).is_file()}


_AUDIT = {"installed": False, "sink": None}


def test_lamp_files_sheeting_tables_psf_and_weights_are_listed_and_travel(lamp_sheet_scene, tmp_path):
    from poevp_optics.apps.run.preflight import check_run
    from poevp_optics.control.predictors import make_predictor
    from poevp_optics.render.renderer import Renderer
    from poevp_optics.render.materials.photometric_lamp import load_distribution

    toml = lamp_sheet_scene
    folder = toml.parent
    spec = load_scene(toml)
    refs = with_hashes(scene_inputs(spec))
    listed = {r.key: (r.kind, r.source) for r in refs}
    a = lambda rel: str((ASSETS_DIR / rel).resolve())       # noqa: E731
    assert listed == {
        "scene file": ("scene", str(toml.resolve())),
        "render.xml": ("scene", str((folder / "scene.xml").resolve())),
        "scene.xml: <texture type='bitmap'> filename ($plate_texture)": ("assets", a("plates/plate_B4713.png")),
        "spectra.lamp.distribution": ("assets", a("lamps/low_beam.ldt")),
        "sheeting.wall_sheeting.source": ("scene", str((folder / "tables" / "sheet.csv").resolve())),
        "relay.measured_file": ("assets", a("psf/relay_example_psf.png")),
        "predictor.weights": ("assets", a("predictor/dmvfn_lite.safetensors")),
        "sensor.qe": ("assets", a("spectra/imx253_mono_qe.csv")),
    }
    # the loaders themselves: every scene or assets/ file Python opens to load, check and build
    # this scene (lamp and sheeting parsed again by the Mitsuba plugins) and its predictor is listed
    load_distribution.cache_clear()                     # read the lamp file again, not from memory
    opened = _opened_by_python(lambda: (check_run(load_scene(toml), "render", memory=False), Renderer(spec.resolved.render),
                                        make_predictor(spec.predictor.name, spec.predictor.weights,
                                                       spec.predictor.resolution)))
    mine = {p for p in opened if p.startswith((str(folder.resolve()), str(ASSETS_DIR.resolve())))}
    assert {a("lamps/low_beam.ldt"), str((folder / "tables" / "sheet.csv").resolve())} <= mine
    assert mine <= {src for _, src in listed.values()}, mine - {src for _, src in listed.values()}
    # a worker whose package assets/ holds none of them gets every file from the bundle
    plan = make_plan("bundle", toml, refs)
    bundle = make_bundle(plan, refs)
    assert bundle.files == 8
    bare = tmp_path / "worker_assets"
    bare.mkdir()
    work = tmp_path / "worker" / "point"
    work.mkdir(parents=True)
    m = materialize(plan, refs, bundle.data, work, assets_dir=bare)
    mirror = work / "lampy"
    for placed in ("lamps/low_beam.ldt", "psf/relay_example_psf.png", "tables/sheet.csv"):
        assert (mirror / placed).is_file(), placed        # where the lookups look before assets/
    assert sorted(o.split("=", 1)[0] for o in m.overrides) == ["predictor.weights", "sensor.qe"]
    worker_spec = load_scene(m.scene, list(m.overrides))
    check_same_inputs(refs, worker_spec, m.path_map)     # the same bytes under the same keys


def test_a_chart_lists_its_reference_cameras_files():
    """dr_chart36 renders the chart for lab_rail's camera (chart.reference_camera): lab_rail's
    TOML, XML and plate texture are inputs of every point."""
    refs = {r.key: r.source for r in scene_inputs(load_scene(SCENES / "dr_chart36"))}
    prefix = "chart.reference_camera: "
    ref = {k[len(prefix):]: v for k, v in refs.items() if k.startswith(prefix)}
    lab = {r.key: r.source for r in scene_inputs(load_scene(SCENES / "lab_rail"))}
    assert ref == lab
    assert ref["scene file"] == str((SCENES / "lab_rail" / "scene.toml").resolve())


def test_a_frame_source_scene_sends_its_frames_and_csvs(tmp_path):
    """exr_highbeam (issue 19: radiance from an EXR sequence, no XML): the bundle lists the files
    its kind reads (sources/kinds.py source_files: every frame of the glob, the boxes CSV), and a
    worker's mirror renders what the client renders."""
    from poevp_optics.sources.kinds import source_files

    client = tmp_path / "client"
    shutil.copytree(SCENES / "exr_highbeam", client / "exr_highbeam")
    toml = client / "exr_highbeam" / "scene.toml"
    spec = load_scene(toml, ["timing.frames=2"])
    refs = with_hashes(scene_inputs(spec))
    frames = sorted((client / "exr_highbeam" / "frames").glob("road_*.exr"))
    assert len(frames) == 13
    listed = {r.key: r.source for r in refs if r.kind == "scene"}
    assert listed == {"scene file": str(toml.resolve()), "source.boxes": str(frames[0].parent / "boxes.csv"),
                      **{f"source.frames[{i}]": str(p) for i, p in enumerate(frames)}}
    assert set(listed.values()) == {str(toml.resolve())} | {str(p.resolve()) for p in source_files(spec.resolved.render)}
    plan = make_plan("bundle", toml, refs)
    work = tmp_path / "worker"
    work.mkdir()
    m = materialize(plan, refs, make_bundle(plan, refs).data, work)
    worker_spec = load_scene(m.scene, ["timing.frames=2", *m.overrides])
    check_same_inputs(refs, worker_spec, m.path_map)
    _assert_worker_renders_like_the_client(tmp_path, spec, worker_spec, m.path_map)


def test_a_sweep_client_reads_a_scenes_inputs_and_memory_without_torch():
    """What a sweep's or search's client does before any point runs (list each scene's inputs,
    the shipped predictor weights among them, and bound its memory) loads no torch, whichever
    predictor the scene names: torch is loaded only where a network runs."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from poevp_optics.apps.run.memory import estimate_run\n"
            "from poevp_optics.apps.sweep.bundle import scene_inputs\n"
            "from poevp_optics.scene.load import load_scene\n"
            "for name in ('highbeam_plate', 'night_road', 'smoke'):\n"
            f"    spec = load_scene({str(SCENES)!r} + '/' + name)\n"
            "    w = [r.asset for r in scene_inputs(spec) if r.key == 'predictor.weights']\n"
            "    print(name, spec.predictor.name, w, estimate_run(spec).total_bytes > 0)\n"
            "print('torch' in sys.modules)\n")
    got = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert got.returncode == 0, got.stderr
    lines = got.stdout.splitlines()
    assert lines == ["highbeam_plate dmvfn_lite ['predictor/dmvfn_lite.safetensors'] True",
                     "night_road track_net ['predictor/track_net.safetensors'] True",
                     "smoke oracle [] True", "False"], got.stdout
    assert (ASSETS_DIR / "predictor" / "dmvfn_lite.safetensors").is_file()
