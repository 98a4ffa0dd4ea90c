"""What a run writes: the writer of a render run's files (the [outputs] keys, `OutputsSpec`, are in
scene/outputs.py; re-exported here)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from poevp_optics import __version__
from poevp_optics.core import runtime
from poevp_optics.analysis.metrics import to_8bit
from poevp_optics.analysis.tonemap import tonemap
from poevp_optics.core.io import write_dn, write_exr, write_png
from poevp_optics.core.units import PHOTON_RADIANCE_UNIT
from poevp_optics.scene.outputs import OutputsSpec  # noqa: F401 (re-exported: it moved to scene/)


def mask_png(levels: np.ndarray, top: int) -> np.ndarray:
    """DMD levels as an 8-bit image (0 dark ... 255 white)."""
    return np.clip(np.rint(levels * 255.0 / top), 0, 255).astype(np.uint8)


def contact_sheet(rows: list[list[np.ndarray]], labels: list[str]) -> np.ndarray:
    """Tile uint8 grey images (rows of frames x columns of kinds) with column labels. Frames wider
    than 320 px are shrunk to 320; frames narrower than their column's longest label are enlarged
    (nearest neighbour: the pixels stay visible as pixels) so no two labels overlap."""
    import cv2

    font, size, gap = cv2.FONT_HERSHEY_SIMPLEX, 0.42, 4
    h, w = rows[0][0].shape
    label_w = max(cv2.getTextSize(lab, font, size, 1)[0][0] for lab in labels) + gap
    scale = min(1.0, 320.0 / w) if w >= label_w else label_w / w
    th, tw = int(round(h * scale)), int(round(w * scale))
    band = 18
    sheet = np.full((band + len(rows) * (th + gap), len(labels) * (tw + gap)), 255, np.uint8)
    for c, lab in enumerate(labels):
        cv2.putText(sheet, lab, (c * (tw + gap) + 4, 13), font, size, 0, 1, cv2.LINE_AA)
    interp = cv2.INTER_AREA if scale <= 1.0 else cv2.INTER_NEAREST
    for r, row in enumerate(rows):
        for c, img in enumerate(row):
            y, x = band + r * (th + gap), c * (tw + gap)
            sheet[y:y + th, x:x + tw] = cv2.resize(img, (tw, th), interpolation=interp)
    return sheet


class OutputWriter:
    """Writes a render run's files, frame by frame, into a staging folder (README's output tour):
    radiance/ (sensor-grid truth and MC error), subframes/, capture/, ldr/, mask/, exposure/,
    reconstruction/, preview*/ and, at `finish`, contact_sheet.png."""

    def __init__(self, spec, camera, renderer, out_dir: Path):
        self.spec, self.camera, self.renderer, self.out = spec, camera, renderer, Path(out_dir)
        self.sheet_rows: list[list[np.ndarray]] = []
        self.sheet_every = max(1, spec.timing.frames // 4)

    def _attrs(self, ex) -> dict:
        s, r = self.spec, self.renderer
        return {"poevp_quantity": "", "poevp_unit": PHOTON_RADIANCE_UNIT,
                "poevp_scene": s.name, "poevp_version": __version__, "poevp_frame": str(ex.index),
                "poevp_t_start_s": repr(ex.t_start_s), "poevp_exposure_s": repr(ex.exposure_s),
                "poevp_render_path": r.plan.mode, "poevp_variant": r.variant, "poevp_spp": str(s.render.spp)}

    def _radiance(self, fc, name: str, attrs: dict) -> None:
        ex, o = fc.exposure, self.spec.outputs
        if o.radiance_exr:
            write_exr(self.out / "radiance" / f"{name}.exr",
                      {"Y": fc.truth_s, "mc_stderr": np.sqrt(self.camera.to_sensor(ex.variance))},
                      {**attrs, "poevp_quantity": "sensor-weighted photon radiance on the sensor grid, "
                                                  "exposure mean; mc_stderr = Monte Carlo standard error"})
        if o.subframes_exr and ex.basis:
            for bname, sub in zip(ex.basis, ex.subframes):
                write_exr(self.out / "subframes" / f"{name}_{bname}.exr", {"Y": sub},
                          {**attrs, "poevp_quantity": f"photon radiance of emitter group {bname!r} at full "
                                                      "drive (mirror grid, guard band included)"})
        elif o.subframes_exr and not self.spec.is_static:
            for k, sub in enumerate(ex.subframes):
                write_exr(self.out / "subframes" / f"{name}_sub{k:03d}.exr", {"Y": sub},
                          {**attrs, "poevp_quantity": f"photon radiance at t = {ex.subframe_times_s[k]!r} s "
                                                      "(mirror grid, guard band included)"})

    def frame(self, fc) -> None:
        """Write one frame's files (`render_run.FrameCapture`)."""
        cam, o = self.camera, self.spec.outputs
        name = f"frame_{fc.exposure.index:04d}"
        attrs = self._attrs(fc.exposure)
        self._radiance(fc, name, attrs)
        bits, max_dn = cam.params.bits, cam.params.max_dn
        write_dn(self.out / "capture" / name, fc.enc.dn, bits)
        if cam.dmd:
            write_dn(self.out / "ldr" / name, fc.ldr.dn, bits)
            write_png(self.out / "mask" / f"{name}.png", mask_png(fc.mask, cam.top_level))
        write_exr(self.out / "exposure" / f"{name}.exr", {"Y": fc.enc.exposure_s},
                  {**attrs, "poevp_quantity": "effective exposure (DMD duty x throughput incl. leakage)",
                   "poevp_unit": "s"})
        write_exr(self.out / "reconstruction" / f"{name}.exr", {"Y": fc.est, "flags": fc.flags},
                  {**attrs, "poevp_quantity": "radiance estimate; flags: 1 saturated, 2 SNR<1, 4 unexposed, "
                                              "8 PSF crosstalk"})
        sheet = o.contact_sheet and fc.exposure.index % self.sheet_every == 0 and len(self.sheet_rows) < 4
        if o.previews or sheet:                  # tone-mapped once for the previews and the sheet
            scene_8, est_8 = _tonemap_pair(fc.truth_s, fc.est, o.tonemap)
        if o.previews:
            write_png(self.out / "preview" / f"{name}.png", scene_8)
            write_png(self.out / "preview_reconstruction" / f"{name}.png", est_8)
        if sheet:
            row = [scene_8, to_8bit(fc.ldr.dn, max_dn).astype(np.uint8)]
            if cam.dmd:
                row.append(mask_png(fc.mask, cam.top_level))
            row += [to_8bit(fc.enc.dn, max_dn).astype(np.uint8), est_8]
            self.sheet_rows.append(row)

    def finish(self) -> None:
        """The contact sheet of the frames collected by `frame`."""
        if self.sheet_rows:
            labels = ["scene (tone-mapped)", "LDR twin"] + (["mask"] if self.camera.dmd else []) + \
                     ["encoded capture", "reconstruction"]
            write_png(self.out / "contact_sheet.png", contact_sheet(self.sheet_rows, labels))


def _tonemap_pair(scene: np.ndarray, estimate: np.ndarray, method: str) -> tuple[np.ndarray, np.ndarray]:
    """The two previews' tone maps, side by side on two threads where the run has two (NumPy
    releases the GIL in its array passes: 0.4 s each at 1920x1080); the same bytes either way."""
    if runtime.run_threads() < 2:
        return tonemap(scene, method), tonemap(estimate, method)
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(2) as pool:
        a, b = pool.submit(tonemap, scene, method), pool.submit(tonemap, estimate, method)
        return a.result(), b.result()
