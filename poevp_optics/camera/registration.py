"""Mirror grid <-> sensor grid: the relay's affine registration of the DMD onto the sensor.

Coordinates are continuous pixel coordinates with pixel centres at integers + 0.5. The map
takes mirror coordinates m to sensor coordinates

    s = scale R(rotation) (m - c_m) + c_s + offset_px,   offset_px = [dx, dy],

about the grid centres c_m, c_s (`[dmd.registration]`). The relay conserves radiance, so a
sensor pixel sees the area average of the DMD-plane radiance over its footprint
(`forward_taps`: each sensor pixel split into oversample^2 sub-areas, each mapped back to the
mirror it lands in; exact to 1/oversample^2 of a pixel's area; off the mirror array: 0). A
uniform mirror image therefore reads the same value on the sensor, and the total flux
(sum x pixel area) is conserved: sum_sensor = scale^2 sum_mirror for an image inside the field.
The inverse direction (`to_mirror`) places a sensor-grid picture (a predicted frame) on the
mirror grid by sampling it at each mirror's centre (bilinear, edges replicated), so a mask
computed from sensor-grid predictions lands on the mirrors that image the highlight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from poevp_optics.core.memo import kept
from poevp_optics.core.params import param


@dataclass(frozen=True)
class RegistrationSpec:
    """[dmd.registration]: affine map mirror grid -> sensor grid (module docstring)."""

    scale: float = param(1.0, gt=0, max=100.0)
    rotation_deg: float = param(0.0, min=-180.0, max=180.0)
    offset_px: tuple[float, float] = param((0.0, 0.0), length=2)



def is_identity(reg) -> bool:
    return reg.scale == 1.0 and reg.rotation_deg == 0.0 and tuple(reg.offset_px) == (0.0, 0.0)


def mirror_coords(reg, sx, sy, mirror_shape, sensor_shape):
    """Inverse map: sensor coordinates -> mirror coordinates (arrays)."""
    hs, ws = sensor_shape
    hm, wm = mirror_shape
    th = math.radians(reg.rotation_deg)
    dx = sx - ws / 2 - reg.offset_px[0]
    dy = sy - hs / 2 - reg.offset_px[1]
    mx = (math.cos(th) * dx + math.sin(th) * dy) / reg.scale + wm / 2
    my = (-math.sin(th) * dx + math.cos(th) * dy) / reg.scale + hm / 2
    return mx, my


def _sensor_coords(reg, mx, my, mirror_shape, sensor_shape):
    """Forward map: mirror coordinates -> sensor coordinates (arrays)."""
    hs, ws = sensor_shape
    hm, wm = mirror_shape
    th = math.radians(reg.rotation_deg)
    dx, dy = mx - wm / 2, my - hm / 2
    sx = reg.scale * (math.cos(th) * dx - math.sin(th) * dy) + ws / 2 + reg.offset_px[0]
    sy = reg.scale * (math.sin(th) * dx + math.cos(th) * dy) + hs / 2 + reg.offset_px[1]
    return sx, sy


def forward_taps(reg, mirror_shape: tuple[int, int], sensor_shape: tuple[int, int],
                 oversample: int = 4) -> tuple[np.ndarray, np.ndarray] | None:
    """Area-weighted resampling mirror grid -> sensor grid, or None when it is the identity
    (identity map and equal shapes). Returns (indices (N, oversample^2) into the flattened
    mirror grid, weights (N, oversample^2)), N = sensor pixels; see the module docstring."""
    if is_identity(reg) and tuple(mirror_shape) == tuple(sensor_shape):
        return None
    hs, ws = sensor_shape
    hm, wm = mirror_shape
    o = (np.arange(oversample) + 0.5) / oversample
    oy, ox = np.meshgrid(o, o, indexing="ij")                        # oversample x oversample grid
    sy, sx = np.meshgrid(np.arange(hs), np.arange(ws), indexing="ij")
    py = (sy[..., None] + oy.ravel()).reshape(hs * ws, -1)
    px = (sx[..., None] + ox.ravel()).reshape(hs * ws, -1)
    mx, my = mirror_coords(reg, px, py, mirror_shape, sensor_shape)
    ix, iy = np.floor(mx).astype(np.int64), np.floor(my).astype(np.int64)
    inside = (ix >= 0) & (ix < wm) & (iy >= 0) & (iy < hm)
    idx = np.where(inside, iy * wm + ix, 0)
    weights = inside.astype(np.float64) / oversample ** 2
    return idx, weights


def apply_taps(image_flat, taps):
    """Resample a flattened DrJit Float mirror-plane image with `forward_taps`."""
    import drjit as dr
    from drjit.auto import Float, UInt32

    idx, w = taps
    out = None
    for j in range(idx.shape[1]):
        v = dr.gather(Float, image_flat, UInt32(idx[:, j].astype(np.uint32))) * Float(w[:, j].astype(np.float32))
        out = v if out is None else out + v
    return out


def apply_taps_numpy(image: np.ndarray, taps, sensor_shape) -> np.ndarray:
    """`apply_taps` for a (H, W) numpy image, in float64."""
    if taps is None:
        return np.asarray(image, dtype=np.float64)
    idx, w = taps
    flat = np.asarray(image, dtype=np.float64).ravel()
    return np.sum(flat[idx] * w, axis=1).reshape(sensor_shape)


#: `to_mirror`'s sampling maps by (scale, rotation, offset, mirror shape, sensor shape): a
#: camera's registration is fixed, and the loop samples several pictures a frame through it.
_REMAP_MAPS: dict = {}
_REMAP_ENTRIES = 2


def _remap_maps(reg, mirror_shape, sensor_shape) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) float32 sensor-pixel coordinates of every mirror's centre, as cv2.remap reads them
    (pixel centres at integers), built once per registration and shapes; read-only."""
    key = (float(reg.scale), float(reg.rotation_deg), tuple(float(v) for v in reg.offset_px),
           tuple(mirror_shape), tuple(sensor_shape))

    def build():
        hm, wm = mirror_shape
        my, mx = np.meshgrid(np.arange(hm) + 0.5, np.arange(wm) + 0.5, indexing="ij")
        sx, sy = _sensor_coords(reg, mx, my, mirror_shape, sensor_shape)
        maps = ((sx - 0.5).astype(np.float32), (sy - 0.5).astype(np.float32))
        for a in maps:
            a.setflags(write=False)
        return maps

    return kept(_REMAP_MAPS, _REMAP_ENTRIES, key, None, build)


def to_mirror(image: np.ndarray, reg, mirror_shape, sensor_shape) -> np.ndarray:
    """A sensor-grid picture sampled at every mirror's centre (bilinear, edges replicated)."""
    import cv2

    img = np.asarray(image, dtype=np.float32)
    if is_identity(reg) and tuple(mirror_shape) == tuple(sensor_shape):
        return img
    map_x, map_y = _remap_maps(reg, mirror_shape, sensor_shape)
    return cv2.remap(img, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def box_to_sensor(box, reg, mirror_shape, sensor_shape):
    """Image box (y0, x0, y1, x1), end-exclusive, on the mirror grid -> the sensor-grid box that
    holds its image (clipped to the sensor; None if it misses the sensor)."""
    if box is None:
        return None
    y0, x0, y1, x1 = box
    cx = np.array([x0, x1, x0, x1], dtype=np.float64)
    cy = np.array([y0, y0, y1, y1], dtype=np.float64)
    sx, sy = _sensor_coords(reg, cx, cy, mirror_shape, sensor_shape)
    hs, ws = sensor_shape
    bx0, bx1 = int(np.clip(math.floor(sx.min()), 0, ws)), int(np.clip(math.ceil(sx.max()), 0, ws))
    by0, by1 = int(np.clip(math.floor(sy.min()), 0, hs)), int(np.clip(math.ceil(sy.max()), 0, hs))
    if bx1 <= bx0 or by1 <= by0:
        return None
    return by0, bx0, by1, bx1
