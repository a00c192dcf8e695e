"""Browser view on a 1M-ray run: page load time and frame time while scrubbing.

    python bench/web_bench.py [--run RUN] [--resolution 0.08] [--frames 12]

Records a dry run of the bundled example at ``--resolution`` mm (0.08: 1343 x 817 =
1.1M rays) unless ``--run`` names a run file, serves it with ``dexmon view``, and drives
Debian's Chromium (``/usr/bin/chromium``, headless, through Playwright) as a user would.
Prints JSON lines:

* ``run``: the run file, its rays and stages;
* ``page_load``: seconds from asking for the page to its first 3-D picture shown;
* ``scrub``: clicks along the timeline, each to another stage; per click the seconds until
  the stage is shown (text) and until the new picture is on the page (p50, max);
* ``play``: pictures a second while the timeline plays;
* ``server_picture``: what one picture costs the server alone (the model at a stage, the
  surface updated, one render), p50 and max s.

The server renders with whatever OpenGL VTK finds (here Mesa's llvmpipe, on the CPU).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

CHROMIUM = "/usr/bin/chromium"


def emit(**kw) -> None:
    print(json.dumps(kw), flush=True)


def record(path: Path, resolution: float) -> None:
    code = subprocess.call([sys.executable, "-m", "monitor.cli", "dry-run", "--clock", "sim", "--speed", "50",
                            "--resolution", str(resolution), "--run", str(path), "--quiet"], cwd=ROOT)
    if code not in (0, 1):
        raise SystemExit(f"dry run failed ({code})")


def picture(page) -> np.ndarray:
    import io

    import imageio.v3 as iio

    return np.asarray(iio.imread(io.BytesIO(page.locator("#view").screenshot())))[..., :3]


def src(page) -> str:
    return page.evaluate("() => { const i = document.querySelector('#view img'); return i ? i.src : ''; }")


def wait_new_src(page, before: str) -> None:
    page.wait_for_function("(b) => { const i = document.querySelector('#view img');"
                           " return i && i.src && i.src !== b && i.complete && i.naturalWidth > 0; }",
                           arg=before, timeout=120_000)


def wait_new_picture(page, before_img: np.ndarray, before_src: str) -> None:
    """Until a picture other than ``before_img`` is shown (VTK may resend the last one first)."""
    s = before_src
    while True:
        wait_new_src(page, s)
        s = src(page)
        img = picture(page)
        if img.shape != before_img.shape or (np.abs(img.astype(np.int16) - before_img).sum(-1) > 24).mean() > 1e-3:
            return


def stage_text(page) -> str:
    return page.inner_text("#stage-text")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--run", default=None)
    ap.add_argument("--resolution", type=float, default=0.08)
    ap.add_argument("--frames", type=int, default=12)
    args = ap.parse_args(argv)
    from playwright.sync_api import sync_playwright

    from monitor.trace_io import RunView

    tmp = tempfile.TemporaryDirectory()
    run = Path(args.run) if args.run else Path(tmp.name) / "bench.dexrun"
    if not args.run:
        record(run, args.resolution)
    with RunView(run) as view:
        emit(event="run", path=str(run), rays=view.frame.n_rays, shape=list(view.frame.shape),
             stages=view.last_stage)
    server_picture(run)
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true"}
    proc = subprocess.Popen([sys.executable, "-m", "monitor.cli", "view", str(run), "--json"], cwd=ROOT,
                            stdout=subprocess.PIPE, text=True, env=env)
    try:
        url = json.loads(proc.stdout.readline())["url"]
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox"])
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            page.set_default_timeout(120_000)
            t0 = time.perf_counter()
            page.goto(url)
            wait_new_src(page, "")
            emit(event="page_load", seconds=round(time.perf_counter() - t0, 3), url=url)
            scrub(page, args.frames)
            play(page)
            browser.close()
    finally:
        proc.terminate()
        proc.wait(30)
    return 0


def server_picture(run: Path, pictures: int = 10) -> None:
    from monitor.trace_io import RunView
    from monitor.web.runmodel import RunModel
    from monitor.web.scene import Scene

    with RunView(run) as view:
        model = RunModel(view)
        scene = Scene(model.frame, model.heights(model.first).copy(), moves=model.moves, tool=model.tool())
        scene.render_window.Render()
        times = []
        for stage in np.linspace(model.first, model.last, pictures).astype(int)[::-1]:
            t0 = time.perf_counter()
            scene.show(model.heights(int(stage)), model.at(int(stage)).tip)
            scene.render_window.Render()
            times.append(time.perf_counter() - t0)
        emit(event="server_picture", pictures=pictures, surface_points=scene.surface.n_points,
             window=list(scene.render_window.GetSize()), p50_s=round(float(np.median(times)), 3),
             max_s=round(float(np.max(times)), 3), opengl=_renderer(scene))
        scene.close()


def _renderer(scene) -> str:
    caps = scene.render_window.ReportCapabilities() or ""
    line = next((x for x in caps.splitlines() if "renderer string" in x), "")
    return line.split(":", 1)[-1].strip()


def scrub(page, frames: int) -> None:
    box = page.locator("#timeline .v-slider").bounding_box()
    to_text, to_picture = [], []
    for k in range(frames):
        x = box["x"] + box["width"] * ((k * 7 % frames) + 0.5) / frames   # jumps back and forth
        before_text, before_src, before_img = stage_text(page), src(page), picture(page)
        t0 = time.perf_counter()
        page.mouse.click(x, box["y"] + box["height"] / 2)
        page.wait_for_function("(s) => document.querySelector('#stage-text').innerText !== s", arg=before_text)
        to_text.append(time.perf_counter() - t0)
        wait_new_picture(page, before_img, before_src)
        to_picture.append(time.perf_counter() - t0)
    emit(event="scrub", clicks=frames, text_p50_s=round(float(np.median(to_text)), 3),
         picture_p50_s=round(float(np.median(to_picture)), 3), picture_max_s=round(float(np.max(to_picture)), 3))


def play(page) -> None:
    page.locator("#timeline .v-slider-thumb").focus()
    page.keyboard.press("Home")
    page.wait_for_function("() => document.querySelector('#stage-text').innerText.startsWith('stage 0 /')")
    seen = [src(page)]
    t0 = time.perf_counter()
    page.click("#play")
    while page.inner_text("#play").strip().lower() != "play" or len(seen) < 2:
        try:
            wait_new_src(page, seen[-1])
        except Exception:  # noqa: BLE001 - playback ended between two pictures
            break
        seen.append(src(page))
        if time.perf_counter() - t0 > 300:
            break
    seconds = time.perf_counter() - t0
    emit(event="play", pictures=len(seen) - 1, seconds=round(seconds, 2),
         pictures_per_s=round((len(seen) - 1) / seconds, 2))


if __name__ == "__main__":
    sys.exit(main())
