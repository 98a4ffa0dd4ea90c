"""The lines `poevp render` ends with: the Monte Carlo error a user can read (the plate first,
then the frame without the pixels clipped in the capture) and which DMD the run simulates, at
what scale, with the overrides (`--dmd-mirrors`) that render it at its own mirrors."""

from __future__ import annotations


#: Mirror arrays (rows, columns) of the DMDs the controllers drive (TI DLP6500 DLPS053: 1920 x 1080;
#: DLP9000 DLPS036: 2560 x 1600): the camera at its own resolution renders one pixel per mirror.
DMD_MIRRORS = {"dlpc900_dlp6500": ("DLP6500", (1080, 1920)), "dlpc900_dlp9000": ("DLP9000", (1600, 2560))}


def mc_error_line(r: dict, spec) -> str:
    """The MC error headline: the ROI (plate) error first, then the frame's over the pixels that
    are not clipped in the capture, its clipped share, and the all-pixel figure beside it."""
    frame, roi = r.get("rel_error"), r.get("rel_error_roi")
    unclipped, clipped = r.get("rel_error_unclipped"), r.get("clipped_fraction")
    if frame is None:
        return ("- (black frame)" if spec.source.renders else
                f"- (radiance from [source] {spec.source.kind})")
    parts = []
    if roi is not None:
        parts.append(f"{roi:.2%} {spec.render.roi_shape or 'ROI'} (ROI)")
    med, p90 = r.get("rel_error_pixel_median"), r.get("rel_error_pixel_p90")
    if unclipped is not None and med is not None:
        parts.append(f"per pixel over the {1 - clipped:.2%} of the frame not clipped in the capture: median "
                     f"{med:.2%}, p90 {p90:.2%} (RMS / mean {unclipped:.2%}, {frame:.2%} with the clipped: "
                     f"set by the brightest pixels)")
    elif unclipped is not None:
        parts.append(f"frame without the {clipped:.3%} of pixels clipped in the capture: RMS / mean "
                     f"{unclipped:.2%} ({frame:.2%} with the clipped)")
    else:
        parts.append(f"{frame:.2%} frame")
    return "; ".join(parts)


def dmd_scale_overrides(spec) -> tuple[str, float, list[str]]:
    """(the DMD's name, scale k = its mirror columns / the render's, the overrides that render it
    at its own mirrors): the resolution, and every size the scene states in mirrors or through
    the image scale (the objective's focal length x k, mask.smooth_px x k, the attenuator's
    serve_min_mirrors x k^2), so the field and the physics stay those of the scaled scene.
    ("", 1, []) for a DMD of unknown mirror count or at its own mirrors already."""
    known = DMD_MIRRORS.get(spec.dmd.controller) if spec.dmd.enabled else None
    if known is None:
        return "", 1.0, []
    name, (h, w) = known
    rh, rw = spec.render.resolution
    if (rh, rw) == (h, w):
        return name, 1.0, []
    k = w / rw
    sets = [f"render.resolution=[{h},{w}]"]
    obj = getattr(spec, "objective", None)
    if obj is not None and getattr(obj, "psf", "delta") != "delta":
        sets.append(f"objective.focal_length_m={obj.focal_length_m * k:.6g}")
    if spec.mask.smooth_px:
        sets.append(f"mask.smooth_px={spec.mask.smooth_px * k:.4g}")
    if spec.attenuator.enabled:
        sets.append(f"attenuator.serve_min_mirrors={round(spec.attenuator.serve_min_mirrors * k * k)}")
    return name, k, sets


def dmd_scale_line(spec) -> str:
    """Which DMD the run simulates and at what scale; how to render its own mirror count."""
    known = DMD_MIRRORS.get(spec.dmd.controller) if spec.dmd.enabled else None
    if known is None:
        return ""
    name, (h, w) = known
    rh, rw = spec.render.resolution
    if (rh, rw) == (h, w):
        return f"\npoevp: the {name} camera at its own {w}x{h} mirrors"
    _, k, sets = dmd_scale_overrides(spec)
    return (f"\npoevp: simulates the {name} camera ({w}x{h} mirrors) at 1/{k:.3g} scale ({rw}x{rh} mirrors, "
            f"the same field); the real resolution (~{k * k:.0f}x the render time): "
            + "--dmd-mirrors, i.e. " + " ".join(f"--set {x}" for x in sets))


def target_line(r: dict) -> str:
    """' (target 1.00 %: met, 16-64 spp)' for an error-targeted render, else ''."""
    if not r.get("target"):
        return ""
    used = r.get("spp_used") or {}
    met = "met" if r.get("met") else r.get("note", "not met")
    return f" (target {r['target']:.2%}: {met}; {used.get('min')}-{used.get('max')} spp)"
