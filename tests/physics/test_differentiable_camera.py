"""The differentiable camera (control/differentiable_camera.py): at the camera's own rounded mask levels
its electrons are `Camera.capture`'s, and its reverse-mode gradient of the plate-white objective
with respect to the paper's Eq. 2 coefficients (Vs, a, b) matches central finite differences of
the same function to 1e-3 relative, on a rendered frame of the smoke scene."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.control.differentiable_camera import FrameModel
from poevp_optics.render.radiance import open_source
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

#: smoke at 24x32 with the paper's law, a 1-px mask blur and a Gaussian relay PSF (sigma 1 px:
#: a guard band and a real convolution in the chain)
TINY = ["render.resolution=[24,32]", "timing.frames=3", "render.spp=4", "mask.law='threshold_exp'",
        "mask.smooth_px=1.0", "relay.psf='gaussian'", "relay.sigma_px=1.0"]


@pytest.fixture(scope="module")
def frame():
    spec = load_scene(SCENES / "smoke", TINY)
    camera = Camera.from_params(spec.resolved.camera)
    assert camera.psf is not None and camera.psf.kernel.shape[0] > 1 and camera.sensor_guard_px > 0
    ex = list(open_source(spec.resolved.render, camera.guard_px).exposures(False))[2]
    truth = camera.dmd_image(ex.radiance.data)
    # a prediction that is not clipped: the frame's radiance on the 8-bit scale, its 99.5th
    # percentile at 250 (a clipped prediction, x = 255, makes a^inf = 0: no gradient)
    pred = np.clip(250.0 * truth / np.percentile(truth, 99.5), 0.0, 255.0)
    box = camera.box_to_sensor(ex.roi)
    model = FrameModel(camera, list(ex.subframes), ex.index, pred, box, times_s=ex.subframe_times_s,
                       smooth_px=spec.mask.smooth_px)
    return camera, ex, model


def test_electrons_at_the_cameras_levels_are_its_capture(frame):
    camera, ex, model = frame
    theta = (150.0, 0.8, 0.1)
    from drjit.llvm.ad import Float64

    levels = model.levels(*(Float64(t) for t in theta), exact=True).reshape(camera.mirror_shape)
    assert 0 < np.mean(levels < camera.top_level) < 1          # the law dims part of the frame
    cap = camera.capture(list(ex.subframes), levels, ex.index, seed=1, times_s=ex.subframe_times_s)
    ours = model.exact_electrons(theta)
    # the camera computes in float32: agreement to a few float32 ulps of the brightest pixel
    np.testing.assert_allclose(ours, cap.signal_e, rtol=2e-5, atol=2e-5 * float(np.max(cap.signal_e)))


@pytest.mark.parametrize("theta", [(150.0, 0.8, 0.1), (190.0, 0.6, 0.3)])
def test_gradient_matches_central_differences(frame, theta):
    _, _, model = frame
    value, grad = model.value_and_grad(theta)
    assert value == pytest.approx(model.value(theta), rel=1e-12)
    assert np.all(np.abs(grad) > 0)
    # central differences of the same float64 function: truncation error O(h^2 f''') and
    # round-off ~ 1e-16 |J| / h; steps 1e-4 of each coefficient's scale keep both below 1e-6
    steps = (1e-2, 1e-4, 1e-4)
    for i, h in enumerate(steps):
        up, down = list(theta), list(theta)
        up[i] += h
        down[i] -= h
        fd = (model.value(up) - model.value(down)) / (2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-3), (i, grad[i], fd)


def test_refinement_lowers_the_objective_or_says_why_it_cannot(frame):
    from poevp_optics.control.differentiable_camera import refine

    _, _, model = frame
    bounds = [(100.0, 250.0), (0.3, 1.0), (0.0, 0.4)]
    r = refine(model, (190.0, 0.6, 0.3), bounds)
    assert r.value < r.value0 and not r.note
    assert all(lo <= t <= hi for t, (lo, hi) in zip(r.theta, bounds))
    # a prediction of 100 everywhere, Vs >= 200: the law keeps every mirror white (sigmoid
    # weight e^-50 at 100 DN below the threshold), so no coefficient moves the capture
    camera, ex, _ = frame
    dark = FrameModel(camera, list(ex.subframes), ex.index, np.full(camera.mirror_shape, 100.0), model.box,
                      times_s=ex.subframe_times_s, smooth_px=1.0)
    flat = refine(dark, (220.0, 0.6, 0.3), [(200.0, 250.0), (0.3, 1.0), (0.0, 0.4)])
    assert flat.note.startswith("flat: no predicted value reaches Vs") and flat.theta == flat.theta0
    assert flat.value == flat.value0 and flat.iterations == 0
