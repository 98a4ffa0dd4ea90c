"""The differentiable camera (control/differentiable_camera.py) through a registration that is not
the identity: the mirror grid shifted by a fraction of a pixel and rotated on the sensor
(camera/registration.py: each sensor pixel the area average of the mirrors its footprint covers).
At the camera's own rounded mask levels its electrons are `Camera.capture`'s, and its
reverse-mode gradient with respect to (Vs, a, b) equals central finite differences of the same
float64 function to 1e-3 relative."""

from __future__ import annotations

import numpy as np
import pytest

from poevp_optics.camera.camera import Camera
from poevp_optics.control.differentiable_camera import FrameModel
from poevp_optics.render.radiance import open_source
from poevp_optics.scene.load import load_scene
from tests.conftest import SCENES

#: smoke at 24x32, the paper's law with a 1-px mask blur and no relay PSF (the registration
#: alone between the mirrors and the sensor), the DMD shifted by (0.6, -0.35) px and turned 4 deg
REGISTERED = ["render.resolution=[24,32]", "timing.frames=3", "render.spp=4", "mask.law='threshold_exp'",
              "mask.smooth_px=1.0", "dmd.registration.offset_px=[0.6, -0.35]", "dmd.registration.rotation_deg=4.0"]


@pytest.fixture(scope="module")
def frame():
    spec = load_scene(SCENES / "smoke", REGISTERED)
    camera = Camera.from_params(spec.resolved.camera)
    ex = list(open_source(spec.resolved.render, camera.guard_px).exposures(False))[2]
    truth = camera.dmd_image(ex.radiance.data)
    pred = np.clip(250.0 * truth / np.percentile(truth, 99.5), 0.0, 255.0)     # not clipped (as the
    box = camera.box_to_sensor(ex.roi)                                        # identity test's)
    model = FrameModel(camera, list(ex.subframes), ex.index, pred, box, times_s=ex.subframe_times_s,
                       smooth_px=spec.mask.smooth_px, mirror_box=ex.roi)
    return camera, ex, model


def test_the_registration_mixes_mirrors_on_the_sensor(frame):
    camera, _, _ = frame
    assert camera.taps is not None
    idx, w = camera.taps
    # a sensor pixel's footprint straddles mirrors: several distinct mirrors with weight in it
    distinct = np.array([len(set(i[wi > 0])) for i, wi in zip(idx, w)])
    assert np.mean(distinct >= 2) > 0.5
    # inside the field the weights sum to 1 (area average); near the edge part falls off the mirrors
    assert np.all(np.sum(w, axis=1) <= 1.0 + 1e-12) and np.median(np.sum(w, axis=1)) == pytest.approx(1.0)


def test_electrons_through_the_registration_are_the_capture(frame):
    camera, ex, model = frame
    from drjit.llvm.ad import Float64

    theta = (150.0, 0.8, 0.1)
    levels = model.levels(*(Float64(t) for t in theta), exact=True).reshape(camera.mirror_shape)
    assert 0 < np.mean(levels < camera.top_level) < 1
    cap = camera.capture(list(ex.subframes), levels, ex.index, seed=1, times_s=ex.subframe_times_s)
    ours = model.exact_electrons(theta)
    # the camera gathers in float32 (weights 1/16): a few float32 ulps of the brightest pixel
    np.testing.assert_allclose(ours, cap.signal_e, rtol=2e-5, atol=2e-5 * float(np.max(cap.signal_e)))


@pytest.mark.parametrize("theta", [(150.0, 0.8, 0.1), (190.0, 0.6, 0.3)])
def test_gradient_through_the_registration_matches_central_differences(frame, theta):
    _, _, model = frame
    value, grad = model.value_and_grad(theta)
    assert value == pytest.approx(model.value(theta), rel=1e-12)
    # computed on the plate's box alone (the mirrors it reads): the whole frame's chain's value
    assert value == pytest.approx(model.objective_full(theta), rel=1e-12)
    assert np.all(np.abs(grad) > 0)
    steps = (1e-2, 1e-4, 1e-4)          # as the identity test: truncation and round-off below 1e-6
    for i, h in enumerate(steps):
        up, down = list(theta), list(theta)
        up[i] += h
        down[i] -= h
        fd = (model.value(up) - model.value(down)) / (2 * h)
        assert grad[i] == pytest.approx(fd, rel=1e-3), (i, grad[i], fd)
