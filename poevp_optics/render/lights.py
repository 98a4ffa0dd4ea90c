"""Light selection: the probability with which next-event estimation picks each emitter.

Mitsuba's path integrator picks one emitter per light sample with probability proportional to
the emitters' `sampling_weight` (Mitsuba 3 docs, Plugin reference > Emitters: `sampling_weight`,
default 1 = uniform), and divides by that probability (unbiased for any weights > 0). The
one-sample estimator f_I / p_I has second moment sum_i E[f_i^2] / p_i, smallest for
p_i ~ sqrt(E[f_i^2]) (a Lagrange multiplier on sum p_i = 1; the discrete case of optimal
importance sampling, Owen, "Monte Carlo theory, methods and examples", 2013, ch. 9). `power` estimates E[f_i^2] from a
pilot: camera rays at `PILOT_GRID` film positions (x `PILOT_SPP`), each emitter's direct
contribution at the first hit (emitter sample x BSDF x visibility), i.e. each emitter's power
toward the camera's view. So a 0.005 cd/m2 sky no longer takes a third of the light samples from
two 120 kcd beams. Weights are floored at `FLOOR` x the largest so no emitter is starved.

With an ROI (`render.roi_shape`) the weights minimise the sum of the frame's and the ROI's
relative variances, sum_g Var_g / M_g^2 (M_g: the pilot's mean direct signal over region g):
the same Lagrange argument gives p_i ~ sqrt(sum_g E_g[f_i^2] / M_g^2) (`roi_weighted_moments`).
A frame-wide pilot alone hardly sees a plate of 0.1 % of the pixels: on night_road its two high
beams got equal weights while the retroreflective plate returns 3x more of the left beam (the
camera sits above it: smaller observation angle), so the plate kept a 0.5 relative error per
light sample (20 % at 8 spp, from light selection alone). Renderer re-selects whenever the
ROI's area changes by more than 25 %; the report's `light_weights` are the last selection.

A camera inside a homogeneous medium (fog: sources/weather.py) scores each emitter as the
single-scattering estimator does (render/materials/single_scatter.py): its light at the first
surface x the transmittance of the camera ray and of the shadow ray, plus its light scattered once
at a point of the camera ray. Light scattered by the fog is no surface's: a pilot of surfaces alone
gave the oncoming low beams, whose light the fog scatters toward us, the floor weight, and their
rare samples made fog_highway's car plate 3x noisier (relative error 0.56 per sample, against 0.15).

The ROI's own box renders (`render.roi_spp`, render/exposures.py add_roi_samples) are a separate
estimate of the same pixels, pooled with the frame's: `power_roi` gives them the weights that
minimise the ROI's variance alone (its pilot region only, render/roi.py own_light_weights). Where
other lamps dominate the frame's pilot (wet_night_road: the oncoming low beams' streaks on the wet
road took 85 % of the light samples, a plate lit by our left beam kept a 1.25 relative error per
sample), the plate's samples go to the lamps that light it (0.19 per sample).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from poevp_optics.core.registry import Registry

PILOT_GRID = 64        # film positions per side of the pilot (normalised film coordinates)
PILOT_SPP = 4          # jittered samples per pilot position
FLOOR = 1e-3           # smallest weight relative to the largest
#: Smallest weight relative to the largest in a ROI's own selection (`power_roi`): a defensive
#: mixture (Hesterberg, "Weighted average importance sampling and defensive mixture
#: distributions", Technometrics 37, 1995) bounding the weight of a lamp the pilot undersampled or
#: that moved since it ran (fog_highway's oncoming low beams, 115 m -> 68 m between two pilots).
ROI_FLOOR = 5e-3


@dataclass(frozen=True)
class LightChoice:
    """How `render.light_selection` sets the emitters' sampling weights."""

    from_pilot: bool       # weights from the pilot estimate (else fixed)
    keep_xml: bool         # keep the XML's own `sampling_weight` values
    roi_own: bool = False  # each ROI's box renders (render.roi_spp) take its own region's weights


LIGHT_SELECTIONS = Registry("light selection")
LIGHT_SELECTIONS.register("power", LightChoice(True, False),
                          source="p_i ~ sqrt(E[f_i^2]) (optimal discrete importance sampling, Owen "
                                 "2013 ch. 9) from a direct-lighting pilot (module docstring)",
                          doc="weights from each emitter's contribution toward the camera's view")
LIGHT_SELECTIONS.register("power_roi", LightChoice(True, False, True),
                          source="p_i ~ sqrt(E[f_i^2]) (Owen 2013 ch. 9) per region: the frame's renders take "
                                 "`power`'s weights, each ROI's box renders the optimum of its own pilot region",
                          doc="as power for the frame; each ROI's own box renders (render.roi_spp) pick the "
                              "emitters by the ROI's pilot alone")
LIGHT_SELECTIONS.register("uniform", LightChoice(False, False),
                          source="Mitsuba 3 docs, Emitters: sampling_weight = 1 (the default)",
                          doc="every emitter picked equally often")
LIGHT_SELECTIONS.register("xml", LightChoice(False, True),
                          source="Mitsuba 3 docs, Emitters: `sampling_weight` set in the scene XML",
                          doc="the user's own weights: each emitter's `sampling_weight` in the XML")


def _film_positions(seed: int, box=None) -> np.ndarray:
    """(2, N) jittered positions on [0, 1)^2 (or on `box` = (u0, v0, u1, v1) in film fractions):
    PILOT_GRID^2 cells x PILOT_SPP."""
    rng = np.random.default_rng(seed)
    g = (np.arange(PILOT_GRID) + 0.5) / PILOT_GRID
    x, y = np.meshgrid(g, g)
    base = np.stack([x.ravel(), y.ravel()])
    pos = np.repeat(base, PILOT_SPP, axis=1) + (rng.random((2, base.shape[1] * PILOT_SPP)) - 0.5) / PILOT_GRID
    if box is not None:
        u0, v0, u1, v1 = box
        pos = np.array([[u0], [v0]]) + pos * np.array([[u1 - u0], [v1 - v0]])
    return np.clip(pos, 0.0, np.nextafter(1.0, 0.0))


def pilot_second_moments(mi, scene, sensor, seed: int = 0, box=None) -> dict[str, float]:
    """Per emitter id: mean over pilot samples of its squared direct contribution at the first
    hit (channels averaged; units of the film's radiance squared)."""
    return pilot_moments(mi, scene, sensor, seed, box)[0]


def pilot_moments(mi, scene, sensor, seed: int = 0, box=None) -> tuple[dict[str, float], float]:
    """({emitter id: E[f_i^2]}, M = E[sum_i f_i]) over pilot samples on the film or on `box`
    (u0, v0, u1, v1 film fractions): the second moments and the mean direct signal."""
    import drjit as dr

    pos = _film_positions(seed, box)
    n = pos.shape[1]
    rng = np.random.default_rng(seed + 1)
    u = lambda k: mi.Float(rng.random(n).astype(np.float32)) if k == 1 else \
        mi.Point2f(*[mi.Float(rng.random(n).astype(np.float32)) for _ in range(k)])
    ray, ray_w = sensor.sample_ray(mi.Float(0.0), u(1), mi.Point2f(mi.Float(pos[0]), mi.Float(pos[1])), u(2))
    medium = sensor.get_medium()
    if medium is not None:                                # fog: single scattering (module docstring)
        return _medium_moments(mi, dr, scene, medium, ray, ray_w, u)
    si = scene.ray_intersect(ray)
    bsdf = si.bsdf(ray)
    ctx = mi.BSDFContext()
    contrib = {}
    for em in scene.emitters():
        ds, w = em.sample_direction(si, u(2))
        shadow = si.spawn_ray_to(ds.p)
        finite = dr.isfinite(ds.dist)
        shadow.d = dr.select(finite, shadow.d, ds.d)
        shadow.maxt = dr.select(finite, shadow.maxt, dr.inf)
        visible = si.is_valid() & (ds.pdf > 0) & ~scene.ray_test(shadow)
        f = bsdf.eval(ctx, si, si.to_local(ds.d))
        contrib[em.id()] = dr.select(visible, ray_w * w * f, 0.0)
    return _moments(dr, contrib, n)


def _medium_moments(mi, dr, scene, medium, ray, ray_w, u) -> tuple[dict[str, float], float]:
    """`pilot_moments` of a camera inside a homogeneous medium, as the single-scattering
    estimator scores them (render/materials/single_scatter.py): each emitter's light at the
    first surface x the camera ray's and the shadow ray's transmittance, plus its light scattered
    once at a point of the camera ray drawn on the fog before that surface."""
    from poevp_optics.render.materials.single_scatter import (medium_coefficients, scatter_point, shadow,
                                                              trace, transmittance)

    on = mi.Bool(True)
    si, t_medium = trace(scene, ray, on)
    sigma_t, sigma_s = medium_coefficients(medium, ray, on)
    t_cam = transmittance(sigma_t, t_medium)
    mei = scatter_point(medium, ray, u(1), t_cam, sigma_t > 0)
    in_fog = (sigma_t > 0) & mei.is_valid() & (mei.t < t_medium)
    phase = mei.medium.phase_function()
    albedo = dr.select(sigma_t > 0, sigma_s / sigma_t, 0.0)
    bsdf = si.bsdf(ray)
    ctx = mi.BSDFContext()
    contrib = {}
    for em in scene.emitters():
        ds, w = em.sample_direction(si, u(2))
        lit = si.is_valid() & (ds.pdf > 0)
        f = bsdf.eval(ctx, si, si.to_local(ds.d), lit)
        c = dr.select(lit, ray_w * w * f * t_cam * shadow(scene, si, ds, sigma_t, lit), 0.0)
        ds_m, w_m = em.sample_direction(mei, u(2), in_fog)
        lit_m = in_fog & (ds_m.pdf > 0)
        p_val, _ = phase.eval_pdf(mi.PhaseFunctionContext(), mei, ds_m.d, lit_m)
        scattered = ray_w * w_m * p_val * albedo * (1.0 - t_cam) * shadow(scene, mei, ds_m, sigma_t, lit_m)
        contrib[em.id()] = c + dr.select(lit_m, scattered, 0.0)
    return _moments(dr, contrib, dr.width(t_cam))


def _moments(dr, contrib, n) -> tuple[dict[str, float], float]:
    """({emitter id: mean squared contribution}, mean summed contribution) of the pilot's samples."""
    dr.eval(*contrib.values())                            # one kernel for all emitters
    out, total = {}, np.zeros(n)
    for k, c in contrib.items():
        arr = np.array(c, dtype=np.float64)               # (channels, n) or (n,)
        arr = np.nan_to_num(arr.mean(axis=0) if arr.ndim > 1 else arr)
        out[k] = float(np.mean(arr ** 2))
        total += arr
    return out, float(np.mean(total))


def roi_weighted_moments(regions: list[tuple[dict[str, float], float]]) -> dict[str, float]:
    """sum_g E_g[f_i^2] / M_g^2 per emitter over regions [(moments, mean signal)]: the moments
    whose square roots minimise sum_g Var_g / M_g^2 (module docstring). A region without
    direct signal (M_g = 0) is left out."""
    out: dict[str, float] = {}
    for moments, mean in regions:
        if not mean > 0:
            continue
        for k, v in moments.items():
            out[k] = out.get(k, 0.0) + v / mean ** 2
    if not out and regions:
        return dict(regions[0][0])
    return out


def set_sampling_weights(params, weights: dict[str, float]) -> None:
    """Write {emitter id: weight} into the loaded scene's `sampling_weight` parameters
    (mi.traverse `params`) and update it."""
    for k, v in weights.items():
        params[f"{k}.sampling_weight"] = float(v)
    params.update()


def weights_from_moments(moments: dict[str, float]) -> dict[str, float]:
    """Sampling weights p_i ~ sqrt(E[f_i^2]), normalised to a largest of 1, floored at FLOOR."""
    root = {k: float(np.sqrt(max(v, 0.0))) for k, v in moments.items()}
    top = max(root.values(), default=0.0)
    if not top > 0:
        return {k: 1.0 for k in moments}
    return {k: max(v / top, FLOOR) for k, v in root.items()}
