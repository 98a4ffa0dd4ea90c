"""Sign sheeting (EN 12899-1 RA1 / RA2) and road studs (EN 1463-1 PRP1) through the
`retroreflective` BSDF (render/materials/furniture_sheeting.py): the class tables come back at
their own geometries.

Coefficient of retroreflection R_A = I / (E_perp A) (CIE 54.2): Mitsuba's `eval` for a light from
`wo` seen from `wi` returns f cos(theta_light) = L / E_perp = R_A / cos(theta_view)
(retroreflective.py), so R_A = eval x cos(theta_view). The BSDF's entrance angle is that of the
bisector of light and view (Helmholtz reciprocity), so light and camera are placed symmetrically
about the tabulated entrance angle beta, coplanar, alpha apart: the table's node is hit exactly.

A road stud is rated by its coefficient of luminous intensity R = I / E_perp (mcd lx-1, EN 1463-1):
its lens of area A (measured on the built mesh) seen at theta_view sends I = L A cos(theta_view),
L = eval x E_perp, so R = eval x A x cos(theta_view).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

#: EN 12899-1:2007 Tables 3 and 4, white, R_A (cd lx-1 m-2) at (alpha, beta) in deg, written out here.
SIGN_CLASSES = {
    "RA1": {(0.2, 5.0): 50.0, (1 / 3, 30.0): 16.0, (2.0, 40.0): 1.5},
    "RA2": {(0.2, 5.0): 180.0, (1 / 3, 30.0): 75.0, (2.0, 5.0): 5.0},
}
#: EN 1463-1 class PRP1 white: R (mcd lx-1) at alpha 0.3 deg, beta 5 deg; 1.0 deg, 20 deg.
STUD_R = {(0.3, 5.0): 220.0, (1.0, 20.0): 5.0}


@pytest.fixture(scope="module")
def mono():
    from poevp_optics.core import runtime
    import poevp_optics.render  # noqa: F401  (installs the plugin hook)

    runtime.set_variant("llvm_ad_mono")


def _dir(theta_deg):
    t = math.radians(theta_deg)
    return [math.sin(t), 0.0, math.cos(t)]


def _eval(sheeting, alpha_deg, beta_deg):
    """eval x cos(theta_view) with light and view symmetric about beta, alpha apart."""
    import drjit as dr
    import mitsuba as mi

    bsdf = mi.load_dict({"type": "retroreflective", "sheeting": sheeting})
    view, light = beta_deg - alpha_deg / 2, beta_deg + alpha_deg / 2
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(*_dir(view))
    si.n = mi.Normal3f(0, 0, 1)
    si.sh_frame = mi.Frame3f(si.n)
    value = float(np.mean(np.asarray(bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(*_dir(light))))))
    return value * math.cos(math.radians(view))


def test_sign_sheeting_classes_return_their_table(mono):
    for cls, table in SIGN_CLASSES.items():
        for (alpha, beta), ra in table.items():
            # 1e-4: the table holds these as nodes; float32 directions and exp/log are good to ~1e-6
            assert _eval(f"en12899_1:{cls}", alpha, beta) == pytest.approx(ra, rel=1e-4), (cls, alpha, beta)
    # ASTM's -4 deg entrance: below the first EN node (5 deg) R_A is held (retroreflective.py)
    assert _eval("en12899_1:RA2", 0.2, -4.0) == pytest.approx(180.0, rel=1e-4)
    # between the nodes, log R_A is linear in log alpha: RA1 at 0.25 deg, beta 5 deg
    p = math.log(50.0 / 35.0) / math.log((1 / 3) / 0.2)
    assert _eval("en12899_1:RA1", 0.25, 5.0) == pytest.approx(50.0 * (0.25 / 0.2) ** -p, rel=1e-4)


def test_road_stud_luminous_intensity(mono):
    from poevp_optics.sources.furniture import FurnitureSpec, furniture_meshes, resolve

    lens = furniture_meshes(resolve(FurnitureSpec(kind="road_stud")))["reflectors"]
    area = float(lens.area)
    assert np.allclose(lens.face_normals, [0, 0, -1])
    for (alpha, beta), r_mcd in STUD_R.items():
        r = _eval("en1463_1:PRP1", alpha, beta) * area            # R_A cos(theta_v) / cos(theta_v) x A
        assert r * 1e3 == pytest.approx(r_mcd, rel=1e-4), (alpha, beta, r * 1e3)
    # a stud 30 m ahead in a 20 kcd beam: I = R E_perp = 0.22 cd lx-1 x 20000 / 30^2 lx = 4.9 cd
    e_perp = 20000.0 / 30.0 ** 2
    assert _eval("en1463_1:PRP1", 0.3, 5.0) * area * e_perp == pytest.approx(0.220 * e_perp, rel=1e-4)
