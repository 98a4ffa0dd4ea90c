"""The lines `poevp render` ends with: the Monte Carlo error a user can read (the plate first,
then the frame without the pixels clipped in the capture), the camera's scale against its scene
file and what it changed (`--scale`, `--resolution`, POEVP_SCALE: scene/scale.py), which DMD the
run simulates, at what scale, with the flag that renders it at its own mirrors, and a run whose
frames are all white initialisation frames."""

from __future__ import annotations

from poevp_optics.scene.scale import scale_text, scaling_for


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
        name = "nearest plate" if spec.render.roi_shape == "plates" else spec.render.roi_shape or "ROI"
        parts.append(f"{roi:.2%} {name} (ROI)")   # "plates": each plate's own in report.json metrics.plates
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


def plural(n: int, word: str) -> str:
    """'1 frame', '3 frames'."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def dmd_scale_overrides(spec) -> tuple[str, float, list[str]]:
    """(the DMD's name, scale k = its mirror columns / the render's, the overrides that render it
    at its own mirrors): the resolution and every size the scene states in mirrors or through the
    image scale (scene/scale.py: the objective's focal length x k, mask.smooth_px x k, the
    attenuator's serve_min_mirrors x k^2, ...), so the field and the physics stay those of the
    scaled scene. ("", 1, []) for a DMD of unknown mirror count or at its own mirrors already."""
    known = DMD_MIRRORS.get(spec.dmd.controller) if spec.dmd.enabled else None
    if known is None:
        return "", 1.0, []
    name, (h, w) = known
    if tuple(spec.render.resolution) == (h, w):
        return name, 1.0, []
    scaling = scaling_for(spec, (h, w), "--dmd-mirrors")
    return name, scaling.scale, list(scaling.sets)


def _value_text(key: str, value) -> str:
    if key == "objective.focal_length_m":
        return f"f {value * 1e3:.2f} mm"
    if key == "predictor.resolution":
        return f"{key} {value[0]}x{value[1]}"
    return f"{key} {value:g}"


def scale_line(scaling) -> str:
    """What a scaled camera changed against its scene file (scene/scale.py Scaling):
    '\npoevp: the camera at 1/6 scale (--scale 1/6) of the scene's 1080x1920: 180x320 mirrors,
    f 11.51 mm, ... (the same field)'; '' for none."""
    if scaling is None or not (scaling.changes or scaling.kept):
        return ""
    (bh, bw), (h, w) = scaling.base_resolution, scaling.resolution
    parts = [f"{h}x{w} mirrors"] + [_value_text(key, new) for key, (_, new) in scaling.changes.items()
                                    if key != "render.resolution"]
    kept = f"; as --set gave them: {', '.join(scaling.kept)}" if scaling.kept else ""
    return (f"\npoevp: the camera at {scale_text(scaling.scale)} scale ({scaling.given}) of the scene's "
            f"{bh}x{bw}: {', '.join(parts)} (the same field){kept}")


def dmd_scale_line(spec, scaling=None) -> str:
    """Which DMD the run simulates and at what scale; how to render its own mirror count (with
    `scaling`, the run's Scaling: the flag in place of the one that scaled it)."""
    known = DMD_MIRRORS.get(spec.dmd.controller) if spec.dmd.enabled else None
    if known is None:
        return ""
    name, (h, w) = known
    rh, rw = spec.render.resolution
    if (rh, rw) == (h, w):
        return f"\npoevp: the {name} camera at its own {w}x{h} mirrors"
    k = w / rw
    head = (f"\npoevp: simulates the {name} camera ({w}x{h} mirrors) at 1/{k:.3g} scale ({rw}x{rh} mirrors, "
            f"the same field); the real resolution (~{k * k:.0f}x the render time): ")
    if scaling is not None and scaling.given != "--dmd-mirrors" and (scaling.changes or scaling.kept):
        flag = "--scale 1" if tuple(scaling.base_resolution) == (h, w) else "--dmd-mirrors"
        if scaling.given.startswith("POEVP_SCALE="):
            return head + f"{flag} ({scaling.given} is set in the environment)"
        return head + f"{flag} in place of {scaling.given}"
    _, k, sets = dmd_scale_overrides(spec)
    return head + "--dmd-mirrors, i.e. " + " ".join(f"--set {x}" for x in sets)


def init_line(report: dict, spec) -> str:
    """'\npoevp: all 1 frame is a white initialisation frame ...' for a DMD run whose frames are
    all the loop's all-white initialisation frames (no predictor ran); '' otherwise."""
    n = report.get("frames")
    if report.get("metrics", {}).get("init_frames") != n or not n:
        return ""
    what = "is a white initialisation frame" if n == 1 else "are white initialisation frames"
    return (f"\npoevp: {'the' if n == 1 else 'all'} {plural(n, 'frame')} {what} (loop.init_frames = "
            f"{spec.loop.init_frames}): no predictor ran, every mask is white (the LDR camera)")


def target_line(r: dict) -> str:
    """' (target 1.00 %: met, 16-64 spp)' for an error-targeted render, else ''."""
    if not r.get("target"):
        return ""
    used = r.get("spp_used") or {}
    met = "met" if r.get("met") else r.get("note", "not met")
    return f" (target {r['target']:.2%}: {met}; {used.get('min')}-{used.get('max')} spp)"
