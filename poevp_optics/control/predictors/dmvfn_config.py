"""The DMVFN family's architecture settings (Hu et al., "A Dynamic Multi-Scale Voxel Flow Network
for Video Prediction", CVPR 2023; `dmvfn_lite` ours, after it) and their inference memory bound,
kept apart from the torch network (dmvfn.py) so that a run's memory estimate and a sweep's
client read them without loading torch."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DMVFNConfig:
    channels: int = 3                     # image channels
    scales: tuple[int, ...] = (4, 4, 4, 2, 2, 2, 1, 1, 1)
    widths: tuple[int, ...] = (160, 160, 160, 80, 80, 80, 44, 44, 44)
    depth: int = 4                        # 3x3 convolutions in each block's body
    routing: bool = True
    input_downsample: int = 1             # lite: blocks see the frames at 1/4 resolution

    @property
    def min_input_px(self) -> int:
        """Smallest frame side (px) the network takes: its coarsest block works at
        1/(input_downsample x scale) resolution and needs at least one pixel there."""
        return self.input_downsample * max(self.scales)

    def activation_bytes(self, h: int, w: int) -> int:
        """Upper bound of inference memory (bytes) on h x w frames: the largest block's input,
        encoder and body activations (float32; blocks run one after another) plus 30 float32
        maps at full size (frames, flows, mask, warps, the OpenCV remap grids)."""
        c_in = 4 * self.channels + 5
        per_px = 0.0
        for s, width in zip(self.scales, self.widths):
            f = self.input_downsample * s
            per_px = max(per_px, (c_in + 5) / f ** 2 + (width / 2) / (2 * f) ** 2
                         + width * (self.depth + 2) / (4 * f) ** 2)
        return int(4 * h * w * (per_px + 30))


FULL = DMVFNConfig()
LITE = DMVFNConfig(channels=1, scales=(4, 2, 1), widths=(64, 48, 32), depth=4, routing=False,
                   input_downsample=4)
