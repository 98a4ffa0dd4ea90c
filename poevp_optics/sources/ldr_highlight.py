"""[source] kind = "ldr_highlight": an LDR video with the paper's artificial highlight (Eq. 3).

He et al., Photonics Research 12(11), 2524 (2024), Sec. 4.A: each frame O of an LDR video gets
"a Hadamard product ... with a grayscale map ... [a] 2D Gaussian distribution whose extreme
point aligns with the center point of license plate, written as H(x,y) = O(x,y)[E·G(x,y)+1],
G(x,y) = exp(-((x-cx)^2+(y-cy)^2)/2R) ... The over-exposure rate E and radius R are parameters
that control the intensity and size of the Gaussian map"; test sets E = 9, 29, 49 and R = 50 on
720x1280 frames (Sec. 6).

**Radius and sigma** (`RADIUS_RULES`). Our copy prints the exponent's denominator as "2R". An
exponent is dimensionless and R is called a radius, a length in pixels, so the default rule
`"sigma"` reads it as 2R^2: G = exp(-d^2 / (2 sigma^2)) with sigma = R (the copy prints the
other squares inline too, "(x-cx)2", so R's square may have been lost the same way). `"literal"`
keeps the printed form, G = exp(-d^2 / (2R)), i.e. sigma = sqrt(R) with R in px read as px^2.
R is the paper's value at 720x1280, scaled as a length to the frame:
R_frame = r_px x sqrt((H / 720) (W / 1280)) (the geometric mean of the two axes' scales; H / 720
for 16:9 frames). G is evaluated at pixel centres (x + 0.5, y + 0.5) about the box centre
((x0 + x1) / 2, (y0 + y1) / 2), box edges in input pixels (frames.py).

**Domain of Eq. 3** (`e_domain`, `E_DOMAINS`). The paper applies Eq. 3 to the stored 8-bit
frames: O "represents the original frames in the LSV-LP dataset" (phone videos, display-encoded),
and the product "makes some pixel values of the original LDR frames increase beyond 255 ...
pixels whose values are over 255 are cut off to 255" (Sec. 4.A). `"display"` follows the paper:
H is formed on the stored values V (in units of 255), then decoded by `transfer` extended above 1
(sRGB: ((V + 0.055) / 1.055)^2.4), so the peak's linear gain is decode(E + 1) / decode(1), about
(E + 1)^2.4: E = 9 is 224x in linear radiance (158x for a 2.2 power law). `"linear"` (default,
this source's earlier reading) forms H on the linearised values: E = 9 is 10x in radiance.

**Per input frame j**: decode (8- or 16-bit PNG/JPEG by glob, or a video frame by OpenCV) ->
value / (2^bits - 1) -> linearise (`TRANSFERS`) -> colour frames: Rec. 709 luminance
Y = 0.2126 R + 0.7152 G + 0.0722 B of the linear values (ITU-R BT.709-6; sRGB has the BT.709
primaries) -> O in [0, 1] -> H = O (E G + 1), G about frame j's plate box (a frame without a
box: H = O) -> photon radiance = scale x H.

| key                 | type    | unit                      | default  | what |
|---------------------|---------|---------------------------|----------|------|
| frames / video      | str     | -                         | one of   | glob of PNG/JPEG frames (sorted) / one video file, relative to the scene |
| transfer            | str     | -                         | "srgb"   | srgb, gamma (with `gamma`) or linear |
| gamma               | float   | -                         | 2.2      | exponent of transfer = "gamma" |
| e                   | float   | -                         | required | over-exposure rate E of Eq. 3 (paper: 9, 29, 49) |
| r_px                | float   | px at 720x1280            | required | radius R of Eq. 3 (paper: 50) |
| radius_rule         | str     | -                         | "sigma"  | how R gives the Gaussian's sigma (above) |
| e_domain            | str     | -                         | "linear" | Eq. 3 on linear values or on stored values (`display`, the paper's) |
| box / boxes         | [4] / str | input px / -            | one of   | constant plate box [x0, y0, x1, y1] / CSV `frame,x0,y0,x1,y1,text` |
| text                | str     | -                         | ""       | plate text with a constant `box` (ground truth) |
| scale               | float   | e- s-1 m-2 sr-1           | one of   | photon radiance of the linear value 1 |
| luminance_cd_per_m2 | float   | cd m-2                    | one of   | luminance of the linear value 1, light of SPD `spectrum` |
| spectrum            | str     | -                         | -        | spectra.py source, with luminance_cd_per_m2 |
| fps, t0_s           | float   | frames s-1, s             | required, 0 | frame j shows t0_s + j / fps |
| subframes           | str     | -                         | "linear" | nearest, linear or integrate (frames.py) |
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from poevp_optics.core.registry import Registry
from poevp_optics.sources import spectra
from poevp_optics.sources.frames import (Box, Clock, FrameSequenceSource, SourceError, SourceKeyError,
                                         check_clock_keys, check_file_keys, check_spectrum_key, frame_files,
                                         photon_radiance_per_cd_per_m2, read_boxes_csv, resolve_path)

KEYS = ("frames", "video", "transfer", "gamma", "e", "r_px", "radius_rule", "e_domain", "box", "boxes", "text",
        "scale", "luminance_cd_per_m2", "spectrum", "fps", "t0_s", "subframes")

#: The paper's frame size for r_px (Sec. 6: R = 50 at 720x1280).
PAPER_FRAME_PX = (720, 1280)


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1:1999 sRGB decoding: V / 12.92 up to 0.04045, else ((V + 0.055) / 1.055)^2.4."""
    v = np.asarray(v, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


#: Decodings of stored values V in [0, 1] to linear values: f(V, gamma) (gamma: the `gamma` key).
TRANSFERS = Registry("LDR transfer")
TRANSFERS.register("srgb", lambda v, gamma: srgb_to_linear(v), source="IEC 61966-2-1:1999 (sRGB)")
TRANSFERS.register("gamma", lambda v, gamma: np.asarray(v, dtype=np.float64) ** gamma,
                   source="power law V^gamma")
TRANSFERS.register("linear", lambda v, gamma: np.asarray(v, dtype=np.float64), source="values already linear")

#: The Gaussian's sigma (px) from Eq. 3's radius R (px, scaled to the frame).
RADIUS_RULES = Registry("Eq. 3 radius rule")
RADIUS_RULES.register("sigma", lambda r: r, source="He et al. 2024 Eq. 3 with the denominator read as "
                                                   "2R^2 (R a length): sigma = R")
RADIUS_RULES.register("literal", math.sqrt, source="He et al. 2024 Eq. 3 as printed, exp(-d^2/(2R)): "
                                                   "sigma = sqrt(R)")

#: Where Eq. 3's product is formed (module docstring, "Domain of Eq. 3").

#: Rec. 709 luminance weights of linear R, G, B (ITU-R BT.709-6, item 3.2).
REC709_LUMA = (0.2126, 0.7152, 0.0722)


def frame_radius_px(r_px: float, frame_shape: tuple[int, int]) -> float:
    """Eq. 3's R at 720x1280 scaled as a length to a frame of `frame_shape` (H, W)."""
    h, w = frame_shape
    return r_px * math.sqrt((h / PAPER_FRAME_PX[0]) * (w / PAPER_FRAME_PX[1]))


def gaussian_map(shape: tuple[int, int], center_xy: tuple[float, float], sigma_px: float) -> np.ndarray:
    """G = exp(-((x - cx)^2 + (y - cy)^2) / (2 sigma^2)) at the pixel centres (x + 0.5, y + 0.5)."""
    h, w = shape
    cx, cy = center_xy
    x = np.arange(w, dtype=np.float64) + 0.5 - cx
    y = np.arange(h, dtype=np.float64) + 0.5 - cy
    return np.exp(-(y[:, None] ** 2 + x[None, :] ** 2) / (2.0 * sigma_px ** 2))


def artificial_highlight(o: np.ndarray, box: Box | None, e: float, sigma_px: float) -> np.ndarray:
    """Paper Eq. 3: H = O (E G + 1), G centred on the plate box; no box: H = O (float64).
    O: (H, W) or (H, W, C) (G is shared by the channels)."""
    o = np.asarray(o, dtype=np.float64)
    if box is None:
        return o
    g = gaussian_map(o.shape[:2], box.center_xy, sigma_px)
    return o * (e * (g[..., None] if o.ndim == 3 else g) + 1.0)


def stored_values(img: np.ndarray) -> np.ndarray:
    """Stored 8/16-bit image -> values V in [0, 1] (float64), channels kept."""
    if img.dtype not in (np.uint8, np.uint16):
        raise TypeError(f"expected 8- or 16-bit values, got {img.dtype}")
    return img.astype(np.float64) / float(np.iinfo(img.dtype).max)


def luminance_of(v: np.ndarray, transfer: str, gamma: float) -> np.ndarray:
    """Stored values V (any range >= 0; (H, W), RGB or RGBA) -> linear luminance."""
    lin = TRANSFERS[transfer](v, gamma)
    if lin.ndim == 3:
        lin = lin[..., :3] @ np.asarray(REC709_LUMA)
    return lin


def linear_luminance(img: np.ndarray, transfer: str, gamma: float) -> np.ndarray:
    """Stored 8/16-bit image (H, W), (H, W, 3) RGB or (H, W, 4) RGBA -> linear O in [0, 1]."""
    return luminance_of(stored_values(img), transfer, gamma)


#: Where Eq. 3's product is formed (module docstring, "Domain of Eq. 3"):
#: (img, box, e, sigma_px, transfer, gamma) -> linear luminance with the highlight.
E_DOMAINS = Registry("Eq. 3 domain")
E_DOMAINS.register("linear", lambda img, box, e, sigma, transfer, gamma: artificial_highlight(
    linear_luminance(img, transfer, gamma), box, e, sigma), source="ours: H = O (E G + 1) on linearised values")
E_DOMAINS.register("display", lambda img, box, e, sigma, transfer, gamma: luminance_of(
    artificial_highlight(stored_values(img), box, e, sigma), transfer, gamma),
    source="He et al. 2024 Sec. 4.A: H = O (E G + 1) on the stored 8-bit values ('pixel values ... "
           "beyond 255'), then decoded")


def highlighted_luminance(img: np.ndarray, box: Box | None, e: float, sigma_px: float, transfer: str,
                          gamma: float, domain: str) -> np.ndarray:
    """Linear luminance of frame `img` with Eq. 3's highlight formed in `domain` (E_DOMAINS)."""
    return E_DOMAINS[domain](img, box, e, sigma_px, transfer, gamma)


def check_keys(src, given: frozenset[str], base_dir: Path) -> None:
    """One of frames / video, box / boxes, scale / luminance_cd_per_m2 (+ spectrum); e, r_px, fps."""
    if ("frames" in given) == ("video" in given):
        raise SourceKeyError("frames", "give one of frames (a glob of PNG/JPEG files) or video (a file "
                             "OpenCV reads) for kind = 'ldr_highlight'")
    for k, what in (("e", "the over-exposure rate E of the paper's Eq. 3 (9, 29, 49 there)"),
                    ("r_px", "the radius R of Eq. 3 in px at 720x1280 (50 there), scaled to the frame")):
        if k not in given:
            raise SourceKeyError(k, f"required for kind = 'ldr_highlight': {what}")
    if ("box" in given) == ("boxes" in given):
        raise SourceKeyError("box", "give one of box = [x0, y0, x1, y1] (input px, constant) or boxes "
                             "(CSV frame,x0,y0,x1,y1,text): the highlight is centred on the plate")
    if "box" in given:
        b = src.box
        if len(b) != 4 or not (b[2] > b[0] and b[3] > b[1]):
            raise SourceKeyError("box", f"expected [x0, y0, x1, y1] with x1 > x0 and y1 > y0, got {list(b)}")
    elif "text" in given:
        raise SourceKeyError("text", "with boxes, the plate text is the CSV's text column")
    if ("scale" in given) == ("luminance_cd_per_m2" in given):
        raise SourceKeyError("scale", "give one absolute anchor: scale (e- s-1 m-2 sr-1 of the linear "
                             "value 1) or luminance_cd_per_m2 (of the value 1, with spectrum)")
    if "luminance_cd_per_m2" in given:
        if "spectrum" not in given:
            raise SourceKeyError("spectrum", "required with luminance_cd_per_m2: the light's SPD")
        check_spectrum_key(src.spectrum)
    elif "spectrum" in given:
        raise SourceKeyError("spectrum", "only used with luminance_cd_per_m2")
    if "gamma" in given and src.transfer != "gamma":
        raise SourceKeyError("gamma", f"only used with transfer = 'gamma' (transfer is {src.transfer!r})")
    check_clock_keys(src, given, times_csv=False)
    check_file_keys(src, given, base_dir, ("video", "boxes"))


class _Video:
    """Frames of one video file, decoded in order by OpenCV (reopened to go back)."""

    def __init__(self, path: Path):
        import cv2

        self.path = path
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise SourceError(f"{path}: source.video: OpenCV cannot open this video")
        self.count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        ok, first = cap.read()
        if not ok or self.count < 1:
            raise SourceError(f"{path}: source.video: no frame could be decoded")
        self._cap, self._pos, self._last = cap, 1, first
        self.shape = first.shape[:2]

    def frame(self, j: int) -> np.ndarray:
        """Frame j as RGB (or grey) uint8."""
        import cv2

        if j < self._pos - 1:
            self._cap.release()
            self._cap, self._pos = cv2.VideoCapture(str(self.path)), 0
        while self._pos <= j:
            ok, img = self._cap.read()
            if not ok:
                raise SourceError(f"{self.path}: source.video: ended at frame {self._pos} (its header "
                                  f"says {self.count} frames)")
            self._last, self._pos = img, self._pos + 1
        img = self._last
        return img[..., ::-1] if img.ndim == 3 else img


def _read_image(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise SourceError(f"{path}: source.frames: not an image OpenCV can read (PNG or JPEG)")
    if img.dtype not in (np.uint8, np.uint16):
        raise SourceError(f"{path}: source.frames: {img.dtype} values: an LDR frame has 8 or 16 bits")
    if img.ndim == 3:
        img = img[..., [2, 1, 0, 3][: img.shape[2]]] if img.shape[2] in (3, 4) else img[..., 0]
    return img


class LdrHighlightSource(FrameSequenceSource):
    """LDR frames, linearised, with Eq. 3's highlight on the plate, in absolute units."""

    kind = "ldr_highlight"

    def __init__(self, scene, guard_px: int, sensor_qe: str):
        src = scene.source
        base = scene.toml_path.parent
        where = str(scene.origin or scene.toml_path)
        self._video = None
        if src.video:
            self._video = _Video(resolve_path(base, src.video))
            files, n, shape = [self._video.path], self._video.count, self._video.shape
            what = f"video {src.video} ({n} frames)"
        else:
            files = frame_files(base, src.frames)
            if not files:
                raise SourceError(f"{where}: source.frames: no file matches {src.frames!r} (relative to {base})")
            n, shape = len(files), _read_image(files[0]).shape[:2]
            what = f"{n} frames {src.frames}"
        self.shape_in = tuple(shape)
        if src.boxes:
            boxes = read_boxes_csv(resolve_path(base, src.boxes), n, self.shape_in)
        else:
            boxes = {j: Box(*src.box, text=src.text) for j in range(n)}
        if src.subframes == "linear" and n < 2:
            raise SourceError(f"{where}: source.subframes: 'linear' needs two frames or more")
        if math.isnan(src.scale):
            response = spectra.sensor_response_e_per_J(spectra.load_spectrum(sensor_qe, emissive=True))
            self.scale = src.luminance_cd_per_m2 * photon_radiance_per_cd_per_m2(src.spectrum, response)
            anchor = f"linear 1 = {src.luminance_cd_per_m2:g} cd m-2 of {src.spectrum} = {self.scale:.6g} e- s-1 m-2 sr-1"
        else:
            self.scale = src.scale
            anchor = f"linear 1 = scale = {src.scale:g} e- s-1 m-2 sr-1"
        r_frame = frame_radius_px(src.r_px, self.shape_in)
        self.sigma_px = RADIUS_RULES[src.radius_rule](r_frame)
        reason = (f"{what} {shape[0]}x{shape[1]}, {TRANSFERS.entry(src.transfer).source}, Eq. 3 highlight "
                  f"E = {src.e:g} ({src.e_domain} values), R = {src.r_px:g} px at 720x1280 -> {r_frame:.4g} px, sigma "
                  f"{self.sigma_px:.4g} px ({src.radius_rule}); {anchor}; {src.fps:g} fps; samples by "
                  f"{src.subframes!r}")
        clock = Clock.uniform(n, src.fps, src.t0_s)
        super().__init__(scene, guard_px, files, clock, self.shape_in, 0, boxes, reason)
        unboxed = [j for j in self.frames_used() if j not in boxes]
        if unboxed:
            self.plan = dataclasses.replace(self.plan, notes=self.plan.notes + (
                f"{len(unboxed)} input frames without a plate box in {src.boxes} get no highlight "
                f"(H = O), e.g. frame {unboxed[0]}",))

    def frame_name(self, j: int) -> str:
        return f"{self.files[0].name}#{j}" if self._video is not None else self.files[j].name

    def decoded(self, j: int) -> np.ndarray:
        """Input frame j as stored (uint8/uint16; RGB, RGBA or grey), size-checked."""
        img = self._video.frame(j) if self._video is not None else _read_image(self.files[j])
        if img.shape[:2] != self.shape_in:
            where = f"{self._video.path} (frame {j})" if self._video is not None else self.files[j]
            raise SourceError(f"{where}: source.frames: {img.shape[0]}x{img.shape[1]} px, but "
                              f"the first frame is {self.shape_in[0]}x{self.shape_in[1]}: every frame must "
                              "have one size")
        return img

    def load(self, j: int) -> np.ndarray:
        src = self.scene.source
        return self.scale * highlighted_luminance(self.decoded(j), self.boxes.get(j), src.e, self.sigma_px,
                                                  src.transfer, src.gamma, src.e_domain)


def open_source(scene, guard_px: int, sensor_qe: str) -> LdrHighlightSource:
    return LdrHighlightSource(scene, guard_px, sensor_qe)


def input_files(scene) -> list[Path]:
    src, base = scene.source, scene.toml_path.parent
    files = [resolve_path(base, src.video)] if src.video else frame_files(base, src.frames)
    return files + ([resolve_path(base, src.boxes)] if src.boxes else [])
