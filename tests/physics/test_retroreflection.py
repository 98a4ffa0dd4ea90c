"""Retroreflective sheeting (materials/retroreflective.py, issue 17).

Rendered: a flat sheet under a point lamp, seen by a camera at observation angle alpha from the
lamp, both at distance D, placed symmetrically about the direction that makes entrance angle beta
with the normal (the coplanar geometry of ASTM E810, bisector at beta). Independently of the
plugin: the sheet's intensity toward the camera is I = R_A E_perp A with E_perp = I_lamp / r^2, so
its radiance is L = I / (A cos theta_v) = R_A I_lamp / (r^2 cos theta_v), plus the diffuse base
rho I_lamp cos(beta_i) / (pi r^2). The luminance coefficient recovered from the render,
R_A = (L - diffuse) r^2 cos(theta_v) / I_lamp, must equal ASTM D4956's Type III white table
(300/250/95 at 0.1/0.2/0.5 deg for beta 4 deg; 180/150/65 for 30 deg) and, beyond the table,
the documented extrapolation.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from poevp_optics.sources import spectra
from poevp_optics.render.renderer import Renderer, absolute_spectrum
from poevp_optics.scene.load import load_scene
from poevp_optics.camera.sensor import IMX253

D_M = 10.0
RHO = 0.5
#: ASTM D4956-01 Table 4, Type III white (cd lx-1 m-2): {beta_deg: {alpha_deg: R_A}}
ASTM_III = {4.0: {0.1: 300.0, 0.2: 250.0, 0.5: 95.0}, 30.0: {0.1: 180.0, 0.2: 150.0, 0.5: 65.0}}

SHEET_XML = """\
<scene version="3.0.0">
    <default name="lamp" value="1"/>
    <default name="base" value="0.5"/>
    <default name="plate_sheeting" value="astm_d4956:III"/>
    <integrator type="path"><integer name="max_depth" value="2"/></integrator>
    <sensor type="perspective" id="camera">
        <float name="fov" value="0.08"/>
        <transform name="to_world"><lookat origin="{cx}, {cy}, {cz}" target="0, 0, 0" up="0, 1, 0"/></transform>
    </sensor>
    <emitter type="point" id="lamp">
        <point name="position" x="{lx}" y="{ly}" z="{lz}"/>
        <spectrum name="intensity" value="$lamp"/>
    </emitter>
    <shape type="rectangle" id="sheet">
        <transform name="to_world"><scale x="2" y="2" z="1"/></transform>
        <bsdf type="retroreflective">
            <string name="sheeting" value="$plate_sheeting"/>
            <spectrum name="reflectance" value="$base"/>
        </bsdf>
    </shape>
</scene>
"""


def _geometry(alpha_deg, beta_deg):
    """Camera and lamp positions: at D_M from the sheet centre, alpha apart, bisector at beta."""
    def unit(angle_deg):
        a = math.radians(angle_deg)
        return np.array([math.sin(a), 0.0, math.cos(a)])

    return D_M * unit(beta_deg - alpha_deg / 2), D_M * unit(beta_deg + alpha_deg / 2)


def _scene(write_scene, alpha_deg, beta_deg, mode, spp):
    cam, lamp = _geometry(alpha_deg, beta_deg)
    toml = f"""
    [render]
    spp = {spp}
    resolution = [8, 8]
    seed = 3
    spectral_mode = "{mode}"
    mc_splits = 8
    [timing]
    frames = 1
    [spectra.lamp]
    kind = "intensity"
    source = "cie:A"
    intensity_cd = 1000.0
    [spectra.base]
    kind = "reflectance"
    source = "neutral:{RHO}"
    [sheeting.plate_sheeting]
    source = "astm_d4956:III"
    """
    xml = SHEET_XML.format(cx=cam[0], cy=cam[1], cz=cam[2], lx=lamp[0], ly=lamp[1], lz=lamp[2])
    return load_scene(write_scene(toml, xml, name=f"sheet_{mode}_{alpha_deg}_{beta_deg}"))


def _astm_extrapolated(alpha_deg, beta_deg, sigma_deg):
    """The documented rule beyond the table (module docstring), written out here: the last
    segment's power law in alpha, rolled off by exp(-(alpha - 0.5)^2 / (2 sigma^2))."""
    row = ASTM_III[beta_deg]
    p = math.log(row[0.5] / row[0.2]) / math.log(0.5 / 0.2)
    return row[0.5] * (alpha_deg / 0.5) ** p * math.exp(-0.5 * ((alpha_deg - 0.5) / sigma_deg) ** 2)


def _recovered_ra(spec, alpha_deg, beta_deg, mean, var):
    """(R_A from the frame mean, its standard error): L -> R_A with the closed form above."""
    cam, lamp = _geometry(alpha_deg, beta_deg)
    response = spectra.sensor_response_e_per_J(spectra.load_spectrum(IMX253.qe, emissive=True))
    i_s = spectra.integrate(response * absolute_spectrum(spec.spectra["lamp"]))   # e- s-1 sr-1
    r = np.linalg.norm(lamp)
    cos_v, cos_i = cam[2] / np.linalg.norm(cam), lamp[2] / r
    diffuse = RHO * cos_i / math.pi * i_s / r**2
    scale = r**2 * cos_v / i_s
    n = mean.size
    return (float(mean.mean(dtype=np.float64)) - diffuse) * scale, math.sqrt(float(var.sum())) / n * scale


CASES = [(a, b) for b in (4.0, 30.0) for a in (0.1, 0.2, 0.5)] + [(1.0, 4.0)]


@pytest.mark.parametrize("mode", ["mono", "spectral"])
def test_rendered_luminance_coefficient_matches_astm_table(write_scene, mode):
    from poevp_optics.render.materials.retroreflective import SHEETINGS, retro_law

    sigma = retro_law(SHEETINGS["astm_d4956:III"]).tail_sigma_deg
    spp = 64 if mode == "mono" else 256
    rows = []
    for alpha, beta in CASES:
        spec = _scene(write_scene, alpha, beta, mode, spp)
        r = Renderer(spec.resolved.render)
        assert r.plan.mode == mode
        mean, var = r.render_with_error(list(range(11, 19)), spp)
        ra, sigma_ra = _recovered_ra(spec, alpha, beta, mean, var)
        expected = ASTM_III[beta][alpha] if alpha in ASTM_III[beta] else _astm_extrapolated(alpha, beta, sigma)
        rows.append((alpha, beta, ra, expected, sigma_ra))
        # Tolerance: 5.4 standard errors of the frame mean (8 independent-seed splits, so the
        # normalised error is Student's t with 7 dof; 5.4 is its two-sided 99.9 % quantile; the
        # spectral path's error is wavelength sampling, the mono path's only the pixel jitter)
        # plus 1e-3 relative for geometry: over the 8x8-pixel patch (0.08 deg at 10 m, 1.4 cm)
        # alpha changes by ~0.1 % of itself and R_A ~ alpha^-1, but the patch is centred, so
        # the mean moves by the second-order term only (<1e-5); float32 directions give
        # |w_o - w_i| to ~3e-5 relative at 0.1 deg.
        assert abs(ra - expected) <= 5.4 * sigma_ra + 1e-3 * expected, (alpha, beta, ra, expected, sigma_ra)
    print("\n".join(f"{mode} alpha={a} beta={b}: R_A rendered {ra:.3f} +- {s:.3f}, table {e:.3f}"
                    for a, b, ra, e, s in rows))


# ------------------------------------------------------------------ the BSDF on its own
@pytest.fixture(params=["llvm_ad_mono", "llvm_ad_spectral"])
def variant(request):
    from poevp_optics.core import runtime

    runtime.set_variant(request.param)
    return request.param


def _bsdf(sheeting="astm_d4956:I", rho=0.3):
    import mitsuba as mi

    return mi.load_dict({"type": "retroreflective", "sheeting": sheeting,
                         "reflectance": {"type": "uniform", "value": rho}})


def _si(wi, n):
    import drjit as dr
    import mitsuba as mi

    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = wi
    return si


def _random_dirs(rng, n, around=None, max_deg=None):
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if around is not None:     # concentrate near `around` so the retro lobe is exercised
        t = rng.uniform(0, math.radians(max_deg), n)[:, None]
        perp = v - (v @ around)[:, None] * around
        perp /= np.linalg.norm(perp, axis=1, keepdims=True)
        v = np.cos(t) * around + np.sin(t) * perp
    return v


def test_reciprocity(variant):
    """f(wi, wo) = f(wo, wi). Mitsuba's eval is f cos(theta_o), so compare eval / cos(theta_o)."""
    import mitsuba as mi

    rng = np.random.default_rng(5)
    n = 4000
    wi = _random_dirs(rng, n)
    wo = np.concatenate([_random_dirs(rng, n // 2, around=wi[0], max_deg=3.0), _random_dirs(rng, n // 2)])
    wi = np.concatenate([np.repeat(wi[:1], n // 2, 0), wi[n // 2:]])
    wo = wo[:n]
    b = _bsdf()
    ctx = mi.BSDFContext()
    vi, vo = mi.Vector3f(*wi.T.astype(np.float32)), mi.Vector3f(*wo.T.astype(np.float32))
    f_io = np.array(b.eval(ctx, _si(vi, n), vo))[0] / wo[:, 2]
    f_oi = np.array(b.eval(ctx, _si(vo, n), vi))[0] / wi[:, 2]
    ok = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    assert np.count_nonzero(f_io[ok] > 1.0) > 100          # the retro lobe was hit
    np.testing.assert_allclose(f_io[ok], f_oi[ok], rtol=2e-5)   # float32 rounding of wi + wo


def test_eval_pdf_sample_agree_and_energy_is_bounded(variant):
    """sample() weight = eval / pdf; bs.pdf = pdf(wo); and the albedo sum(weight)/N, i.e. the
    retroreflected + diffuse fraction, equals eta(beta) + rho <= efficiency + rho."""
    import mitsuba as mi
    from poevp_optics.render.materials.retroreflective import SHEETINGS, retro_law

    law = retro_law(SHEETINGS["astm_d4956:I"])
    b, ctx, n = _bsdf(rho=0.3), mi.BSDFContext(), 200_000
    for beta in (0.0, 20.0, 60.0):
        wi = mi.Vector3f(math.sin(math.radians(beta)), 0.0, math.cos(math.radians(beta)))
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed(7, n)
        bs, w = b.sample(ctx, _si(wi, n), sampler.next_1d(), sampler.next_2d())
        val, pdf = b.eval_pdf(ctx, _si(wi, n), bs.wo)
        w, val, pdf, bpdf = (np.array(w)[0], np.array(val)[0], np.array(pdf), np.array(bs.pdf))
        good = bpdf > 0
        np.testing.assert_allclose(pdf[good], bpdf[good], rtol=1e-6)
        np.testing.assert_allclose(w[good], val[good] / pdf[good], rtol=1e-5)
        # the albedo estimate's standard error is std(w)/sqrt(n); eta(beta) comes from the
        # plugin's quadrature (32 azimuths x 1200 angles), good to ~1e-4
        albedo, se = w.mean(), w.std() / math.sqrt(n)
        eta = float(np.interp(beta, np.arange(18) * 5.0, law.eta_rows))
        assert abs(albedo - (0.3 + eta)) <= 4 * se + 2e-3, (beta, albedo, eta, se)
        assert albedo - 0.3 <= SHEETINGS["astm_d4956:I"].efficiency + 4 * se


def test_sampling_chi2_on_a_wide_lobe(variant):
    """Mitsuba's chi^2 goodness-of-fit test of sample() against pdf(). The presets' lobes (<1 deg
    core) are narrower than the test's histogram bins, so the same code runs on a wide table."""
    import mitsuba as mi
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    import tempfile
    from pathlib import Path

    table = "# efficiency = 0.3\n" + "\n".join(
        f"{a},{b},{r}" for b, rows in ((4, (0.02, 0.006, 0.001)), (40, (0.012, 0.004, 0.0006)))
        for a, r in zip((5.0, 15.0, 30.0), rows))
    path = Path(tempfile.mkdtemp()) / "wide.csv"
    path.write_text(table)
    for wi in ([0.0, 0.0, 1.0], [math.sin(0.7), 0.0, math.cos(0.7)]):
        sample, pdf = BSDFAdapter("retroreflective", {"type": "retroreflective", "sheeting": f"file:{path}",
                                                      "reflectance": {"type": "uniform", "value": 0.4}}, wi=wi)
        chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf,
                             sample_dim=3, sample_count=400_000, res=101, ires=32)
        assert chi2.run(), chi2.messages


def test_table_errors_name_the_source(tmp_path):
    from poevp_optics.render.materials.retroreflective import SheetingError, parse_sheeting, retro_law

    with pytest.raises(SheetingError, match="unknown preset"):
        parse_sheeting("astm_d4956:IX")
    with pytest.raises(SheetingError, match="above its efficiency"):
        retro_law(parse_sheeting("astm_d4956:III;efficiency=0.01"))
    bad = tmp_path / "bad.csv"
    bad.write_text("# efficiency = 0.1\n0.2,4,70\n0.5,4,80\n")
    with pytest.raises(SheetingError, match="must fall"):
        parse_sheeting(f"file:{bad}")


def test_scene_key_errors_are_one_line(write_scene):
    from poevp_optics.core.exceptions import SceneError
    cam, lamp = _geometry(0.2, 4.0)
    xml = SHEET_XML.format(cx=cam[0], cy=cam[1], cz=cam[2], lx=lamp[0], ly=lamp[1], lz=lamp[2])
    base = """
    [spectra.lamp]
    kind = "intensity"
    source = "cie:A"
    intensity_cd = 1000.0
    [spectra.base]
    kind = "reflectance"
    source = "neutral:0.5"
    """
    for extra, key in [('[sheeting.plate_sheeting]\nsource = "astm_d4956:V"', "sheeting.plate_sheeting"),
                       ('[sheeting.plate_sheeting]\nsource = "astm_d4956:I"\nefficiency = 1.5',
                        "sheeting.plate_sheeting.efficiency"),
                       ('[sheeting.plate_sheeting]\nsource = "astm_d4956:I"\ncolour = 1', "sheeting.plate_sheeting.colour")]:
        folder = write_scene(base + extra, xml, name=key.replace(".", "_"))
        with pytest.raises(SceneError) as e:
            load_scene(folder)
        assert key in str(e.value) and "\n" not in str(e.value)


def test_printed_characters_blend(write_scene):
    """The plate's use: a `blendbsdf` of ink and sheeting. With a uniform weight w on the sheeting
    (bitmap weights act the same per texel) the recovered coefficient is w R_A + (1 - w) x ink's
    diffuse term, here ink reflectance 0.03 and w = 0.6 at the 0.2 deg / 4 deg table point."""
    alpha, beta, w, ink = 0.2, 4.0, 0.6, 0.03
    spec = _scene(write_scene, alpha, beta, "mono", 16)
    xml = spec.xml_path.read_text().replace(
        '<bsdf type="retroreflective">',
        f'<bsdf type="blendbsdf"><float name="weight" value="{w}"/>'
        f'<bsdf type="diffuse"><spectrum name="reflectance" value="{ink}"/></bsdf>'
        '<bsdf type="retroreflective">').replace("</bsdf>\n    </shape>", "</bsdf></bsdf>\n    </shape>")
    spec.xml_path.write_text(xml)
    r = Renderer(load_scene(spec.toml_path).resolved.render)
    mean, var = r.render_with_error(list(range(11, 19)), 16)
    ra, sigma_ra = _recovered_ra(spec, alpha, beta, mean, var)
    # _recovered_ra removed the full diffuse base rho; the blend keeps w rho and adds (1 - w) ink
    cam, lamp = _geometry(alpha, beta)
    cos_v, cos_i = cam[2] / D_M, lamp[2] / D_M
    diffuse_fix = ((w - 1) * RHO + (1 - w) * ink) * cos_i * cos_v / math.pi
    expected = w * ASTM_III[beta][alpha] + diffuse_fix
    assert abs(ra - expected) <= 5.4 * sigma_ra + 1e-3 * expected, (ra, expected)


def test_the_tail_solved_once_is_kept_and_equals_a_fresh_solve(tmp_path, monkeypatch):
    """The tail's roll-off (`_solve_tail`: a quadrature and bisection, 1-1.5 s a table) is kept
    on disk: a second law of the same table reads it, bit for bit, without solving; a damaged
    copy is solved again with one note; another efficiency is another answer."""
    from poevp_optics.render.materials import retroreflective as rr

    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    table = rr.SHEETINGS["astm_d4956:III"]
    first = rr.RetroLaw(table)                                   # solved, kept
    kept = list((tmp_path / "retro").glob("tail-*.npz"))
    assert len(kept) == 1

    def refuse(law):
        raise AssertionError("solved again")

    monkeypatch.setattr(rr, "_solve_tail", refuse)
    again = rr.RetroLaw(table)
    assert again.tail_sigma_deg == first.tail_sigma_deg
    np.testing.assert_array_equal(again.eta_rows, first.eta_rows)
    monkeypatch.undo()
    monkeypatch.setenv("POEVP_CACHE_DIR", str(tmp_path))
    fresh = rr._solve_tail(first)
    assert fresh[0] == first.tail_sigma_deg
    np.testing.assert_array_equal(fresh[1], first.eta_rows)

    kept[0].write_bytes(kept[0].read_bytes()[:100])              # cut short
    assert rr.RetroLaw(table).tail_sigma_deg == first.tail_sigma_deg
    other = rr.parse_sheeting(f"astm_d4956:III;efficiency={min(0.99, 1.1 * table.efficiency):.4f}")
    assert rr.RetroLaw(other).tail_sigma_deg != first.tail_sigma_deg
    assert len(list((tmp_path / "retro").glob("tail-*.npz"))) == 2
