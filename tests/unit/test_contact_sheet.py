"""The contact sheet's column titles stay inside their columns, whatever the frame size: the
title band over each column holds exactly that title, as cv2 draws it alone in a band of the
column's width (no ink of a neighbour, nothing cut off); frames smaller than the title are
enlarged by whole pixels, frames over 320 px shrunk."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from poevp_optics.apps.run.outputs import contact_sheet

LABELS = ["scene (tone-mapped)", "LDR twin", "mask", "encoded capture", "reconstruction"]


@pytest.mark.parametrize("shape", [(12, 20), (45, 80), (180, 320), (540, 960)])
def test_titles_stay_in_their_columns(shape):
    rng = np.random.default_rng(0)
    rows = [[rng.integers(0, 256, shape, dtype=np.uint8) for _ in LABELS] for _ in range(2)]
    full = contact_sheet(rows, LABELS)
    ncol = len(LABELS)
    col_w = full.shape[1] // ncol
    for c, lab in enumerate(LABELS):
        alone = np.full((18, col_w), 255, np.uint8)
        cv2.putText(alone, lab, (4, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.42, 0, 1, cv2.LINE_AA)
        assert (alone < 128).any(axis=0)[-3:].sum() == 0, (shape, lab)      # fits with room to spare
        np.testing.assert_array_equal(full[:18, c * col_w:(c + 1) * col_w], alone, err_msg=f"{shape} {lab}")
    if shape[1] > 320:
        assert col_w <= 324                       # shrunk to 320 px (+ the gap)
    tile = full[18:18 + 4, :col_w - 4]
    assert tile.shape[1] >= shape[1] or shape[1] > 320
