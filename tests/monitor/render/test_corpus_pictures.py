"""Replay pictures of the corpus parts (../shared/corpus/parts, when present): a clean
OpenCAMLib finishing pass with its 6 mm ball is a calm deviation map, not rainbow static.

The run files are recorded here straight from the simulator (every chunk of moves one
stage), the way a session writes them, so the test does not depend on a dry run's polls.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from tests.monitor.render.imagecheck import check_image, hue_shares
from tests.monitor.run_helpers import record_program

PARTS = Path(os.environ.get("DEXMON_SHARED", Path(__file__).resolve().parents[3].parent / "shared")) / "corpus" / "parts"
pytestmark = pytest.mark.skipif(not PARTS.is_dir(), reason="../shared/corpus/parts is not present")

#: part: (program, design, stock box x0,y0,z0,x1,y1,z1 mm)
CORPUS = {
    "sphere_on_plate": ("sphere_on_plate_ball6_finish.ngc", "sphere_on_plate.stl",
                        (0.0, 0.0, -1.0, 76.4923, 76.4923, 30.8718)),
    "carpet1": ("carpet1_ball6_finish.ngc", "carpet1.stl", (0.0, -82.0, -10.0, 152.0, 66.0, 5.1979)),
}


@pytest.fixture(scope="module", params=sorted(CORPUS))
def corpus_run(request, tmp_path_factory):
    prog, design, stock = CORPUS[request.param]
    run = tmp_path_factory.mktemp("corpus") / f"{request.param}.dexrun"
    record_program(run, PARTS / prog, PARTS / design, stock, resolution=0.5, stages=40)
    return request.param, run


def test_clean_finishing_pass_is_a_calm_deviation_map(corpus_run):
    from monitor.render import meaning
    from monitor.render.runpicture import RunPictures
    from monitor.trace_io import RunView

    name, run = corpus_run
    with RunView(run) as view:
        pics = RunPictures(view, size=400)
        img = pics.picture(view.last_stage)
        assert pics.color_by == "deviation"
        rows = pics.live.picture_shape[0]
        model = img[:rows]
        # the part fills the frame
        assert (~(model == np.array((28, 30, 36), np.uint8)).all(axis=2)).mean() > 0.85
        # few hues: the neutral grey of the part within tolerance, and only where the ball
        # cannot reach (material left) a blue; no gouge red, no random move colours
        hues = hue_shares(model)
        assert (hues > 0.02).sum() <= 4, np.round(hues, 3)
        err = pics.errors(np.ascontiguousarray(pics.crop(view.state_at(view.last_stage)[0])))
        idx = meaning.deviation_index(err, pics.tol)
        assert (idx[np.isfinite(err)] == 0).mean() > 0.8          # most of the part within tolerance
        by_move = RunPictures(view, size=400, color_by="move").picture(view.last_stage)[:rows]
        assert (hue_shares(by_move) > 0.02).sum() > (hues > 0.02).sum()   # what the old default looked like
    check_image(img, f"corpus_{name}_end.png", threshold=6.0)
