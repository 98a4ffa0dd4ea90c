"""Per-region exposure controller: what a real POE-VP camera knows of the scene's brightness.

A clipped pixel says only "at least saturated", so no single clipped frame tells how far over
the range a highlight is. The controller keeps, on the mirror grid, an estimate D of the
photo-electrons every mirror would send with the all-white mask ("demand"), built only from what
the camera has: its previous masks and captures.

| quantity        | where the pixel was not clipped            | where it was clipped |
|-----------------|--------------------------------------------|----------------------|
| D_t (e-)        | demodulated estimate e / rel(mask) (exact up to noise) | new region: max(P x saturation, k x lower bound); clipped before: max(k x lower bound, carried D_t-1) |

- lower bound: saturation / rel(mask), the reconstruction's value of a clipped pixel;
- P = `mask.first_guess` (default 40 x saturation): the prior for a region never measured,
  i.e. clipped behind the white initialisation frames. The law aims at `target` (0.6), so the
  first loop frame puts a region X times over saturation at about 0.6 X / P of full scale and
  clips it only above P / target = 67x (the 8-bit DMD's coarse low levels round the level
  down: 1/255 steps are 25-33 % apart at levels 3-4). One 8-bit frame reads a plate from about
  0.1 of full scale (PP-OCRv4 here: white 0.106 read, 0.078 misread, 0.047 missed) to 1.0, an
  11x window; plates under high beams are ~5-300x over saturation (60x), so no prior avoids
  every lost first frame. A clipped frame loses the read, a dim one only the band, so P puts the
  window on the lower decade, where the default scene's plate is (p90 white 7x over at its
  120 kcd beams, 57x at 10x the beams): both read on the first loop frame (0.11 and 0.96).
  Brighter plates clip once and are bracketed (below). On a road scene `mask.prior_beam_cd`
  ties P to our own beams: P is the prior under beams of that intensity and scales with
  [road].highbeam's intensity_cd (the light a plate returns from our beams is proportional to
  them, and a camera knows its own beams; scene/resolve.py prior_first_guess).
- k = `mask.clip_step` (default 2): the bracket after a clip. A clipped measurement says only
  X > lower bound L, so the next guess is k L: the next frame puts X at target X / (k L), i.e.
  0.3 of full scale if X was just above L (still read), and clips again only if X > k L /
  target (the bracket grows 3.3x per clipped frame: 1000x is found after three clipped frames
  from P = 40). The old rule (guess 32 L) put X just above L at 0.6 / 32 = 0.02 of full scale,
  and with the 8-bit levels' rounding a 12x-beam plate came out at 0.1 after one clip with
  k = 4 (issue 18: 0.09 at 10x with 32), a lost read.
- carried D_t-1: the region's history. The previous demand, grey-dilated by the mask's motion
  radius R = ceil(3 smooth_px), so a region known to be 500x stays 500x where the highlight
  moved onto mirrors that were white (their own lower bound is only 1x);
- moved D_t (`mask.carry = "extrapolate"`, `moved_e`): each bright region of D_t moved on one
  frame at the velocity of its bounding box over the last two frames (region_motion.py), for a
  highlight whose image moves faster than R per frame and a predictor that lags it; the mask
  law takes the larger of it and its own demand everywhere. Off by default ("dilate");
- `clip_frames`: consecutive frames each region has been clipped (dilated with the region),
  reported per frame; a clipped pixel with clip_frames = 0 before is a new region.

Exposure time (exposure_time.py): before the mask, the controller picks the frame's sensor
exposure T_e and the DMD's bit depth B (the largest whose PWM fits T_e) so that the brightest
regions sit at the mask's fine levels (a step of a few per cent) rather than at levels 1-6 of
255: the coarse attenuation is in T_e, the shaping in the mask. With it, the bracket after a
repeated clip is `mask.time_clip_step` (100) instead of k (T_e is continuous, so a capture far
below the band is still a measurement: exposure_time.py).

The `exposure_controller` mask law (masks.py) takes where the highlight will be from the
prediction and how bright it is from D, then picks per mirror the DMD level that puts the
signal in the target band (`mask.band_low` .. `mask.band_high` of the sensor's full scale, aim
at `mask.target`). The band and the search are ours; the demodulated estimate is the paper's
"modulated capture divided by the mask" (Sec. 3); the search after a clipped measurement is the
bracketing used by auto-exposure controllers (e.g. Nourani-Vatani & Roberts, ACRA 2007: a
saturated image gives only a bound, so the exposure is stepped by a bounded factor, not
jumped).
"""

from __future__ import annotations

import numpy as np


def grey_dilate(img: np.ndarray, radius_px: int) -> np.ndarray:
    """Grey dilation (max filter) over a square of half-width `radius_px` (edges replicated)."""
    import cv2

    if radius_px <= 0:
        return np.asarray(img, dtype=np.float32)
    k = np.ones((2 * radius_px + 1, 2 * radius_px + 1), np.uint8)
    return cv2.dilate(np.asarray(img, dtype=np.float32), k, borderType=cv2.BORDER_REPLICATE)


def full_scale_electrons(params, fraction) -> np.ndarray:
    """Electrons that read `fraction` of the sensor's full scale (top code max_dn):
    (fraction max_dn - offset_dn) / gain_dn_per_e, >= 0. `params`: sensor.SensorParams."""
    f = np.asarray(fraction, dtype=np.float64)
    return np.maximum(f * params.max_dn - params.offset_dn, 0.0) / params.gain_dn_per_e


class ExposureController:
    """The demand map D and the clip history of each region (module docstring). State is real:
    it is the camera's memory of past captures."""

    def __init__(self, first_guess: float, clip_step: float, radius_px: int, saturation_e: float,
                 extrapolate: bool = False, white_step: float | None = None):
        """first_guess: assumed over-exposure of a never-measured clipped region (x saturation);
        clip_step: the guess after a repeated clip (x the new lower bound);
        radius_px: motion radius over which a region's history is carried (mirrors);
        saturation_e: electrons at which the sensor clips;
        extrapolate: keep the previous demand too, for `moved_e`;
        white_step: the bracket where the clipped mirror was white (its exposure the scene's
        own: a lower bound of only ~1x), default clip_step (exposure_time.py sets clip_step to
        its wider bracket for captures dimmed by the mask or a shortened exposure)."""
        self.first_guess = float(first_guess)
        self.clip_step = float(clip_step)
        self.radius_px = int(radius_px)
        self.saturation_e = float(saturation_e)
        self.white_step = self.clip_step if white_step is None else float(white_step)
        self.demand_e: np.ndarray | None = None
        self.clip_frames: np.ndarray | None = None
        self.rel: np.ndarray | None = None
        self.extrapolate = bool(extrapolate)
        self.prev_demand_e: np.ndarray | None = None
        # per region of the last capture, the sigma its miss asks for (envelope.region_sigma), mirrors
        self.region_sigma: np.ndarray | None = None

    def observe(self, e_white: np.ndarray, clipped: np.ndarray, rel: np.ndarray) -> None:
        """Take one capture in (mirror grid): e_white, the all-white electrons it implies (the
        lower bound where clipped); clipped, its saturated pixels; rel, the exposure each mirror
        had relative to white (the displayed mask)."""
        e = np.maximum(np.nan_to_num(np.asarray(e_white, dtype=np.float64), nan=0.0, posinf=1e30), 0.0)
        clip = np.asarray(clipped, dtype=bool)
        k = self.clip_step if self.white_step == self.clip_step else np.where(
            np.asarray(rel, dtype=np.float64) < 1.0 - 1e-6, self.clip_step, self.white_step)
        step = np.maximum(e, self.saturation_e) * k                  # k x lower bound
        if self.demand_e is not None:
            frames = grey_dilate(self.clip_frames, self.radius_px)
            carried = grey_dilate(self.demand_e, self.radius_px).astype(np.float64)
        else:
            frames = np.zeros(clip.shape, np.float32)
            carried = np.zeros(clip.shape, np.float64)
        new = frames <= 0                                              # never clipped here before
        guess = np.maximum(np.maximum(step, carried), np.where(new, self.first_guess * self.saturation_e, 0.0))
        if self.extrapolate:
            self.prev_demand_e = self.demand_e
        self.demand_e = np.where(clip, guess, e).astype(np.float32)
        self.clip_frames = np.where(clip, frames + 1, 0).astype(np.float32)
        self.rel = np.asarray(rel, dtype=np.float32)

    def held_e(self) -> np.ndarray | None:
        """The demand carried to the next frame: D dilated by the motion radius (None before the
        first capture)."""
        if self.demand_e is None:
            return None
        return grey_dilate(self.demand_e, self.radius_px).astype(np.float64)

    def moved_e(self) -> np.ndarray | None:
        """D's bright regions (>= saturation) moved on one frame at their boxes' velocity over
        the last two frames (region_motion.py), dilated by the motion radius; None unless
        `extrapolate` and two frames were seen."""
        from poevp_optics.control.region_motion import extrapolate

        if not self.extrapolate or self.prev_demand_e is None:
            return None
        moved = extrapolate(self.prev_demand_e, self.demand_e, self.saturation_e)
        return grey_dilate(moved, self.radius_px).astype(np.float64)

    def summary(self) -> dict:
        """Per-frame numbers for the report: clipped mirrors and their longest clip history."""
        if self.clip_frames is None:
            return {}
        clipped = self.clip_frames > 0
        return {"clipped_mirrors": int(np.count_nonzero(clipped)),
                "max_clip_frames": int(self.clip_frames.max()) if clipped.any() else 0,
                "max_demand_x_saturation": float(self.demand_e.max() / self.saturation_e)}
