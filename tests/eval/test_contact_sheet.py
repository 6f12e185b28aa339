"""Contact sheets (eval/contact_sheet.py): tiles at one width, labels above them, and a sheet of
bounded size whatever the photos' shapes."""

import numpy as np
import torch

from lumos3d_cli.eval.contact_sheet import contact_sheet


def test_tiles_are_scaled_to_one_width_and_tall_strips_are_bounded():
    landscape, portrait, strip = torch.rand(3, 375, 500), torch.rand(3, 500, 375), torch.ones(3, 2000, 14)
    sheet = contact_sheet([[(landscape, "a"), (portrait, "b")], [(strip, "c")]], tile_width=100)
    # row 1: 22-px labels over 75 and 133 px tiles; row 2: the 14x2000 strip at most 200 px tall (it was 14,286)
    assert sheet.shape == (22 + 133 + 4 + 22 + 200 + 4, 2 * (100 + 4), 3) and sheet.dtype == np.uint8
    row_two = sheet[22 + 133 + 4 + 22:][:200, :100]
    assert row_two[:, 0].min() == 255 and row_two[:, 2:].max() == 0  # the strip, 1-2 px wide, then padding
