"""Colour by meaning: the deviation map's bands and the marks of a top view."""

from __future__ import annotations

import numpy as np

from monitor.render import meaning, shaded
from sim.tolerance import Tolerance


def test_deviation_bands_neutral_red_blue_saturating_at_the_range_of_interest():
    tol = Tolerance(gouge=0.05, undercut=0.1, interest=1.0)
    n = meaning.SCALE_STEPS
    e = np.array([0.0, -0.05, 0.1, np.nan, -0.051, -1.0, -5.0, 0.101, 1.0, np.inf])
    idx = meaning.deviation_index(e, tol)
    assert idx.tolist() == [0, 0, 0, 0, 1, n, n, n + 1, 2 * n, 2 * n]
    pal = meaning.deviation_palette()
    red, blue = pal[idx[5]].astype(int), pal[idx[8]].astype(int)
    assert red[0] > red[1] + 100 and red[0] > red[2] + 100          # deep gouge: red
    assert blue[2] > blue[0] + 100 and blue[2] > blue[1] + 100      # much material left: blue
    grey = pal[0].astype(int)
    assert grey.max() - grey.min() < 20                              # within tolerance: neutral


def test_axes_mark_the_work_origin_and_ticks():
    from sim.frame import Frame

    f = Frame.top(-10.0, -5.0, 50.0, 35.0, 0.25)
    img = np.zeros((f.nv, f.nu, 3), np.uint8)
    meaning.draw_axes(img, f, 1)
    c, r = shaded.to_pixels(f, np.array([[0.0, 0.0, 0.0]]))[0].round().astype(int)
    assert (img[r, c] == 255).all()                                  # the origin's white dot
    x_arrow = (img == np.array(meaning.AXIS_X_COLOR, np.uint8)).all(axis=2)
    y_arrow = (img == np.array(meaning.AXIS_Y_COLOR, np.uint8)).all(axis=2)
    assert x_arrow[r, c + 5:c + 20].any() and y_arrow[r - 20:r - 5, c].any()   # X right, Y up
    ticks = (img[-3:] == np.array(meaning.TICK_COLOR, np.uint8)).all(axis=2).any(axis=0)
    assert ticks.sum() >= 3                                          # X0, X20, X40 along the bottom


def test_moves_feeds_solid_rapids_dashed():
    from sim.frame import Frame

    f = Frame.top(0.0, 0.0, 40.0, 20.0, 0.25)
    img = np.zeros((f.nv, f.nu, 3), np.uint8)
    meaning.draw_moves(img, f, np.array([[2.0, 5, 0], [2.0, 15, 0]]), np.array([[38.0, 5, 0], [38.0, 15, 0]]),
                       np.array([False, True]))
    feed_row = img[int(round(f.nv - 1 - 5 / 0.25))]
    rapid_row = img[int(round(f.nv - 1 - 15 / 0.25))]
    feed = (feed_row == np.array(shaded.PATH_COLOR, np.uint8)).all(axis=1)
    rapid = (rapid_row == np.array(meaning.RAPID_COLOR, np.uint8)).all(axis=1)
    assert feed[8:152].all()                                         # solid
    assert 0.3 < rapid[8:152].mean() < 0.7                           # dashed
