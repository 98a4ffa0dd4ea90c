"""The plate recogniser (analysis/plate_ocr.py): it reads texts that mix 0/O, 1/I and 8/B through
the whole-frame ALPR path where PP-OCRv4's general recogniser does not; its training never saw a
scene's text; its data is reproducible; its weights load safely."""

import json

import numpy as np
import pytest
import torch

from poevp_optics.analysis.plate_ocr import CHARSET, INPUT_H, INPUT_W, decode, default_weights, load_plate_ocr, prepare
from poevp_optics.analysis.recognition import alpr_read, correct
from poevp_optics.apps.train.plate_ocr_data import dataset, plate_crop, scene_texts, training_texts
from poevp_optics.core.weights import WeightsError
from poevp_optics.sources.plates import plate_texture

#: The toll_or_junction scene's texts: nothing but the pairs a reader confuses.
CONFUSABLE = ("IO 8B 01", "OB 180 I", "B1 0O 88", "BO 81 IO")


def _frame(text: str, height_px: int) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """An 8-bit frame with `text`'s plate `height_px` tall on a dark car body: the texture
    area-averaged onto the pixels, white at 150 DN, ink at 5 %, a 0.8 px Gaussian blur (the
    relay), 2 DN of noise (seeded)."""
    import cv2

    tex = plate_texture(text, sheeting_pattern=False).astype(np.float32) / 255.0
    w = int(round(height_px * 520 / 110))
    small = cv2.resize(tex, (w, height_px), interpolation=cv2.INTER_AREA)
    img = np.full((240, 480), 12.0, np.float32)
    y0, x0 = 100, 120
    img[y0:y0 + height_px, x0:x0 + w] = 150.0 * (0.05 + 0.95 * small)
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + 2.0 * np.random.default_rng(height_px).standard_normal(img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), (y0, x0, y0 + height_px, x0 + w)


@pytest.mark.parametrize("height_px", [26, 34])
def test_plate_recogniser_reads_every_confusable_text_through_whole_frame_alpr(height_px):
    """At 26 and 34 px (the toll scene's mid and near plates) the detector + plate recogniser
    read all four texts exactly; PP-OCRv4's general recogniser, on the same frames, misreads at
    least one (its language prior turns O between digits into 0): the frames are hard."""
    plate, general = [], []
    for text in CONFUSABLE:
        frame, box = _frame(text, height_px)
        plate.append(alpr_read(frame, box, recogniser="plate").text)
        general.append(alpr_read(frame, box).text)
    assert all(correct(r, t) for r, t in zip(plate, CONFUSABLE)), f"plate recogniser read {plate}"
    assert not all(correct(r, t) for r, t in zip(general, CONFUSABLE)), f"PP-OCRv4 read every one: {general}"


def test_training_never_saw_a_scene_text():
    """The shipped weights' training and validation streams (their recorded seeds and sizes,
    regenerated as training drew them) hold no text any shipped scene draws today."""
    meta = json.loads(default_weights().with_suffix(".json").read_text())
    held = scene_texts()
    assert {"IO8B01", "B10O88", "NR17RA"} <= held
    for split in ("train", "val"):
        rec = meta["data"][split]
        stream = training_texts(rec["seed"], rec["crops"], set(meta["held_out_texts"]))
        assert len(stream) == rec["crops"]
        assert not {t.replace(" ", "") for t in stream} & held


def test_dataset_is_reproducible_and_seeds_differ():
    held = scene_texts()
    x1, t1, h1 = dataset(5, 24, held)
    x2, t2, h2 = dataset(5, 24, held)
    _, t3, h3 = dataset(6, 24, held)
    assert h1 == h2 and t1 == t2 and np.array_equal(x1, x2)
    assert h3 != h1 and t3 != t1
    assert x1.shape == (24, INPUT_H, INPUT_W) and x1.dtype == np.float32


def test_crop_holds_the_plate_at_the_asked_height():
    """The crop's rows span the plate (its ink box at least) at the asked height: between 0.68 x
    and 1.7 x the plate's height (ink box 75/110 of it, margins up to 0.35 x it on each side)."""
    for i in range(40):
        crop = plate_crop("AB 1234", np.random.default_rng(i), height_px=30)
        assert 0.68 * 30 - 1 <= crop.shape[0] <= 1.7 * 30 + 2, crop.shape
        assert crop.dtype == np.uint8


def test_prepare_normalises_levels_and_keeps_aspect():
    """A two-level crop (40 and 200 DN, both over 5 % of it) scaled down by area: the dark level
    maps to 0 and the bright to 1; its 2.5:1 aspect fills 80 of 160 columns, the rest its median."""
    crop = np.full((64, 160), 40, np.uint8)
    crop[16:48, 32:128] = 200
    x = prepare(crop)
    assert x.shape == (INPUT_H, INPUT_W)
    assert x[0, 0] == pytest.approx(0.0, abs=1e-6) and x[16, 40] == pytest.approx(1.0, abs=1e-6)
    assert np.all(x[:, 81:] == x[0, 0])                            # padded with the median: dark
    assert x[16, 79] == pytest.approx(0.0, abs=1e-6)               # the crop's own right edge is dark
    with pytest.raises(ValueError, match="too small"):
        prepare(np.zeros((1, 30), np.uint8))


def test_ctc_greedy_decoding_collapses_repeats_and_blanks():
    seq = [0, 1 + CHARSET.index("A"), 1 + CHARSET.index("A"), 0, 1 + CHARSET.index("A"), 0,
           1 + CHARSET.index("0"), 1 + CHARSET.index("O")]
    lp = torch.full((len(seq), 1, len(CHARSET) + 1), -20.0)
    for t, k in enumerate(seq):
        lp[t, 0, k] = 0.0
    text, conf = decode(lp)[0]
    assert text == "AA0O" and conf == pytest.approx(1.0, abs=1e-6)


def test_weights_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a safetensors file")
    with pytest.raises(WeightsError, match="bad.safetensors: not a readable safetensors"):
        load_plate_ocr(bad)
    with pytest.raises(WeightsError, match="not found"):
        load_plate_ocr(tmp_path / "missing.safetensors")
    other = default_weights().parents[1] / "predictor" / "track_net.safetensors"
    with pytest.raises(WeightsError, match="not plate recogniser weights"):
        load_plate_ocr(other)


def test_alpr_with_the_plate_recogniser_on_an_empty_frame_and_a_bad_name():
    empty = np.full((120, 240), 10, np.uint8)
    r = alpr_read(empty, (40, 40, 66, 163), recogniser="plate")
    assert r.text == "" and r.detections == 0
    with pytest.raises(ValueError, match="recogniser 'tesseract'"):
        alpr_read(empty, (40, 40, 66, 163), recogniser="tesseract")


def test_scene_library_counts_each_recogniser_on_captures_and_ideal_images():
    """benchmarks/scene_library.py `plate_reads` over a two-frame report: the init frame and the
    plate under 20 px are not counted; on the one counted frame (`IO 8B 01`, 26 px) the plate
    recogniser reads the capture and the ideal image, and each recogniser's tally is its own."""
    from benchmarks.scene_library import plate_reads

    frame, box = _frame("IO 8B 01", 26)
    plate = {"id": "mid", "in_view": True, "box": list(box), "height_px": 26, "white": {"encoded": 0.55}}
    report = {"per_frame": [{"index": 0, "init": True, "plates": [plate]},
                            {"index": 1, "plates": [plate]},
                            {"index": 2, "plates": [{**plate, "height_px": 12}]}]}
    kept = {i: {"capture": frame} for i in range(3)}
    reads = plate_reads(report, kept, 20, {"mid": "IO 8B 01"})
    assert set(reads["mid"]) == {"plate", "ppocr"}
    assert reads["mid"]["plate"] == (1, 1, [], 1)
    k, n, texts, _ = reads["mid"]["ppocr"]
    assert n == 1 and k + len(texts) == 1
