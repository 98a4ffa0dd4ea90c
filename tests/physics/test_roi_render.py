"""The ROI box render (render.roi_spp, Renderer.render_box; issue 27) is the same estimator as
Mitsuba's own render restricted to the box: same mean (unbiased) and same error per sample.

Reference: mi.render of the whole frame at REF_SPP (independent-seed replicates), its own
variance known. The box render's pixels must agree with it within their combined standard
errors: z = difference / estimated standard error, each from 16 independent-seed parts, is
t-distributed with 15 dof (E[z^2] = 1.15, sd of its mean over ~280 pixels ~0.11), so a mean
z^2 < 1.6 is a 4-sigma band; a bias of a few standard errors would exceed it, and its error estimate at a given spp must match
that of mi.render at the same spp (both stratify each pixel's samples) within a factor 1.5.
The pooled frame + ROI variance follows (n1^2 v1 + n2^2 v2) / (n1 + n2)^2: tested against the
scatter of independent repeats.
"""

from __future__ import annotations

import numpy as np

from poevp_optics.core.seeds import render_seeds
from poevp_optics.render.renderer import Renderer
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

REF_SPP = 2048
SPLITS = 16        # variances with 15 dof: z = d / sigma_hat is t-distributed, E[z^2] = 15/13 = 1.15


def _renderer(*sets):
    spec = load_scene(SCENES / "highbeam_plate", ["render.resolution=[92,160]", *sets])
    r = Renderer(spec.resolved.render)
    r.set_time(float(spec.subframe_times_s(0)[0]))
    return r


def test_box_render_is_unbiased_and_as_accurate_as_mitsubas_render():
    r = _renderer()
    y0, x0, y1, x1 = box = r.roi_box()
    ref, ref_var = r.render_with_error(render_seeds(5, 0, 0, SPLITS), REF_SPP)
    ref, ref_var = ref.astype(np.float64)[y0:y1, x0:x1], ref_var[y0:y1, x0:x1]
    m, v, used = r.render_box_with_error(render_seeds(6, 0, 0, SPLITS), 128, box)
    assert m.shape == (y1 - y0, x1 - x0) and used >= 128
    ok = (v + ref_var) > 0
    z2 = (m - ref)[ok] ** 2 / (v + ref_var)[ok]
    assert ok.sum() > 100 and np.mean(z2) < 1.6, (ok.sum(), np.mean(z2))
    # error per sample: the box render vs mi.render at the same spp, pooled over 4 seed pairs
    eb = ef = 0.0
    for k in range(4):
        _, vb, _ = r.render_box_with_error(render_seeds(7, k, 0, 2), 64, box)
        _, vf = r.render_with_error(render_seeds(8, k, 0, 2), 64)
        eb += np.mean(vb)
        ef += np.mean(vf[y0:y1, x0:x1])
    assert 1 / 1.5 < np.sqrt(eb / ef) < 1.5, np.sqrt(eb / ef)


def test_roi_samples_pool_with_the_frame_and_their_variance_is_honest():
    from poevp_optics.render.exposures import add_roi_samples

    r = _renderer("render.roi_spp=32", "render.spp=8")
    spec = r.scene
    y0, x0, y1, x1 = r.roi_box()
    means, variances = [], []
    for k in range(12):
        m, v = r.render_with_error(render_seeds(11, k, 0, 2), 8)
        mm, vv = add_roi_samples(spec, r, k, 0, m, v, r.last_used_spp)
        assert np.array_equal(mm[:y0 - 1], m[:y0 - 1])               # outside the box: untouched
        means.append(np.mean(mm[y0:y1, x0:x1], dtype=np.float64))
        variances.append(np.mean(vv[y0:y1, x0:x1]))
    # the box mean's scatter over repeats vs the pooled variance's prediction (pixel errors
    # correlate little): ratio of variances within a factor 3 (11 dof: P(F > 3) ~ 1e-2 each side
    # for the sample variance alone; the prediction is generous for correlations)
    pred = np.mean(variances) / ((y1 - y0) * (x1 - x0))
    got = np.var(means, ddof=1)
    assert 1 / 4 < got / pred < 4, got / pred
    # the pooled estimate is ~ 5x (40 / 8 spp) less variable than the frame's alone
    _, v8 = r.render_with_error(render_seeds(12, 0, 0, 2), 8)
    assert np.mean(variances) < 0.5 * np.mean(v8[y0:y1, x0:x1])
