"""A plate recogniser trained on the plate font: a small CRNN (convolutions, a bidirectional GRU,
CTC) that reads a detected plate's crop as a sequence of A-Z and 0-9.

Why a second recogniser: PP-OCRv4's (analysis/recognition.py) is a general scene-text model whose
language prior reads a round O between digits as a zero and a slashed 0 between letters as an O
(texts mixing 0/O, 1/I, 8/B read wrong at every height up to 40 px on a clean synthetic plate).
ALPR systems read plates with a recogniser trained on their country's plate font; the paper's
protocol (Sec. 6) is a YOLOv5 detector and a CRNN (Shi, Bai, Yao, "An End-to-End Trainable
Neural Network for Image-based Sequence Recognition", TPAMI 2017) trained on plates. This is
that CRNN, trained on the project's own plate font (sources/plates.py, Go Regular) drawn at 14-46
px plate heights with a camera's blur, noise and exposure (apps/train/plate_ocr_data.py), on
texts drawn apart from every scene's (apps/train/train_plate_ocr.py records the command, data
hash, split and budget in the weights).

Input: a grayscale crop around the plate (what the detector found), scaled to `INPUT_H` rows
keeping its aspect, squeezed or padded to `INPUT_W` columns, levels normalised between its 5th
and 95th percentiles. Output: greedy CTC decoding (Graves et al., ICML 2006) and the mean of the
emitted characters' probabilities as confidence.
"""

from __future__ import annotations

import functools
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from poevp_optics.core.paths import ASSETS_DIR
from poevp_optics.core.weights import WeightsError, load_state, read_weights_file, write_weights_file
from poevp_optics.core import runtime

runtime.torch_threads()          # the run's thread count, where it was set before torch loaded

#: The characters a plate may hold; CTC's blank is class 0.
CHARSET = "0123456789ABCDEFGHIJKLMNOPQRSTUVWXYZ"
INPUT_H, INPUT_W = 32, 160      # px: the network's input (a 520 x 110 mm plate is 4.7:1)


@dataclass(frozen=True)
class PlateOcrConfig:
    """Channels of the five convolutions and the GRU's hidden size per direction."""

    channels: tuple[int, ...] = (16, 32, 48, 48, 64)
    hidden: int = 64


class PlateCRNN(nn.Module):
    """(N, 1, INPUT_H, INPUT_W) -> (T = INPUT_W / 4, N, len(CHARSET) + 1) log-probabilities."""

    def __init__(self, cfg: PlateOcrConfig = PlateOcrConfig()):
        super().__init__()
        self.cfg = cfg
        c = (1, *cfg.channels)
        pools = [(2, 2), (2, 2), None, (2, 1), (4, 1)]      # 32 rows -> 1, 160 columns -> 40
        layers: list[nn.Module] = []
        for i, pool in enumerate(pools):
            layers += [nn.Conv2d(c[i], c[i + 1], 3, padding=1, bias=False), nn.BatchNorm2d(c[i + 1]), nn.ReLU()]
            if pool:
                layers.append(nn.MaxPool2d(pool))
        self.conv = nn.Sequential(*layers)
        self.rnn = nn.GRU(c[-1], cfg.hidden, bidirectional=True, batch_first=False)
        self.head = nn.Linear(2 * cfg.hidden, len(CHARSET) + 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        f = self.conv(x).squeeze(2).permute(2, 0, 1)          # (T, N, C)
        return self.head(self.rnn(f)[0]).log_softmax(-1)


def prepare(crop: np.ndarray) -> np.ndarray:
    """A grayscale (or BGR) crop -> float32 (INPUT_H, INPUT_W): aspect kept to INPUT_H rows, then
    squeezed to INPUT_W columns if wider or padded on the right with its own median; levels set
    to 0 at the 5th and 1 at the 95th percentile."""
    import cv2

    img = np.asarray(crop, dtype=np.float32)
    if img.ndim == 3:
        img = img.mean(axis=2)
    h, w = img.shape
    if h < 2 or w < 2:
        raise ValueError(f"plate crop too small to read: {h}x{w} px")
    width = max(1, min(INPUT_W, int(round(w * INPUT_H / h))))
    interp = cv2.INTER_AREA if h > INPUT_H else cv2.INTER_CUBIC
    small = cv2.resize(img, (width, INPUT_H), interpolation=interp)
    out = np.full((INPUT_H, INPUT_W), float(np.median(small)), np.float32)
    out[:, :width] = small
    lo, hi = np.percentile(out, (5.0, 95.0))
    return ((out - lo) / max(hi - lo, 1.0)).astype(np.float32)


def decode(log_probs: torch.Tensor) -> list[tuple[str, float]]:
    """Greedy CTC decoding of (T, N, C) log-probabilities: [(text, mean probability of its
    characters)] per batch item (0.0 for an empty text)."""
    p, idx = log_probs.detach().exp().max(-1)
    out = []
    for n in range(idx.shape[1]):
        chars, probs, prev = [], [], 0
        for t in range(idx.shape[0]):
            k = int(idx[t, n])
            if k != 0 and k != prev:
                chars.append(CHARSET[k - 1])
                probs.append(float(p[t, n]))
            prev = k
        out.append(("".join(chars), float(np.mean(probs)) if probs else 0.0))
    return out


def encode(text: str) -> list[int]:
    """A plate text -> CTC targets (1-based indices into CHARSET; spaces dropped)."""
    return [CHARSET.index(c) + 1 for c in text.upper() if c in CHARSET]


# ----------------------------------------------------------------------------- weights
def default_weights() -> Path:
    return ASSETS_DIR / "recogniser" / "plate_crnn.safetensors"


def save_plate_ocr(model: PlateCRNN, path: Path, meta: dict) -> None:
    write_weights_file(path, model, {"config": asdict(model.cfg), "model": "plate_crnn", "charset": CHARSET, **meta})


def load_plate_ocr(path: Path) -> tuple[PlateCRNN, dict]:
    """A PlateCRNN from safetensors (never pickle); one-line errors on a missing, corrupt,
    non-finite or mismatched file."""
    path = Path(path)
    tensors, meta = read_weights_file(path, "plate recogniser weights", model="plate_crnn")
    try:
        if json.loads(meta["charset"]) != CHARSET:
            raise WeightsError(f"{path}: trained for another character set ({meta['charset']})")
        raw = json.loads(meta["config"])
        cfg = PlateOcrConfig(channels=tuple(raw["channels"]), hidden=int(raw["hidden"]))
    except (KeyError, TypeError, json.JSONDecodeError) as e:
        raise WeightsError(f"{path}: missing or bad 'config' metadata ({e})") from None
    model = load_state(PlateCRNN(cfg), tensors, path)
    return model, {k: json.loads(v) for k, v in meta.items() if k not in ("config", "model", "charset")}


@functools.lru_cache(maxsize=2)
def _shipped(path: str) -> PlateCRNN:
    return load_plate_ocr(Path(path))[0]


def read_crops(crops: list[np.ndarray], weights: Path | None = None) -> list[tuple[str, float]]:
    """[(text, confidence)] for grayscale plate crops, with the shipped weights unless `weights`."""
    if not crops:
        return []
    model = _shipped(str(weights or default_weights()))
    x = torch.from_numpy(np.stack([prepare(c) for c in crops]))[:, None]
    with torch.no_grad():
        return decode(model(x))
