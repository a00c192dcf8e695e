"""Helpers for the browser-view tests: the system's Chromium driven by Playwright (never a
browser Playwright downloads), and a ``dexmon`` command serving a page in a subprocess."""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]
#: Debian's chromium package
CHROMIUM = os.environ.get("DEXMON_CHROMIUM", "/usr/bin/chromium")
#: generous: a page, a server and VTK start on a busy 2-core machine
WAIT_S = 60.0


def chromium_or_skip() -> str:
    """The Chromium executable, or skip saying what to install."""
    path = CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium")
    if not path:
        pytest.skip(f"no Chromium at {CHROMIUM}: apt-get install chromium (the browser-view tests drive it)")
    pytest.importorskip("playwright.sync_api", reason="pip install playwright (its own browsers are not used)")
    return path


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Served:
    """``python -m monitor.cli ARGS`` in a subprocess, its stdout JSON lines in a queue."""

    def __init__(self, args: list[str]):
        env = {**os.environ, "PYVISTA_OFF_SCREEN": "true", "MPLBACKEND": "Agg"}
        # Ctrl-C must reach it even when the suite itself was started in the background
        # (a shell's `cmd &` ignores SIGINT, and an ignored signal stays ignored across exec)
        self.proc = subprocess.Popen([sys.executable, "-m", "monitor.cli", *args], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env,
                                     preexec_fn=_default_sigint)
        self.lines: queue.Queue = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, args=(self.proc.stdout, self.lines), daemon=True).start()
        threading.Thread(target=self._read_err, daemon=True).start()

    @staticmethod
    def _read(stream, out: queue.Queue) -> None:
        for line in stream:
            try:
                out.put(json.loads(line))
            except ValueError:
                out.put({"text": line.rstrip("\n")})
        out.put(None)

    def _read_err(self) -> None:
        for line in self.proc.stderr:
            self.stderr.append(line)

    def event(self, name: str, timeout: float = WAIT_S) -> dict:
        """The next JSON line whose ``event`` is ``name`` (skipping others)."""
        while True:
            try:
                rec = self.lines.get(timeout=timeout)
            except queue.Empty:
                raise AssertionError(f"no {name!r} event in {timeout} s; stderr: {''.join(self.stderr)[-2000:]}")
            if rec is None:
                raise AssertionError(f"ended before a {name!r} event; stderr: {''.join(self.stderr)[-2000:]}")
            if rec.get("event") == name:
                return rec

    def interrupt(self, timeout: float = WAIT_S) -> int:
        """Ctrl-C, as a user stops the page; the exit status."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            raise

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def open_browser(playwright, executable: str):
    return playwright.chromium.launch(executable_path=executable, headless=True,
                                      args=["--no-sandbox", "--disable-dev-shm-usage"])


def view_picture(page) -> np.ndarray:
    """The 3-D view's picture as shown on the page, RGB uint8 (h, w, 3)."""
    import io

    import imageio.v3 as iio

    png = page.locator("#view").screenshot()
    return np.asarray(iio.imread(io.BytesIO(png)))[..., :3]


def picture_src(page) -> str:
    return page.evaluate("() => { const i = document.querySelector('#view img'); return i ? i.src : ''; }")


def wait_new_picture(page, before: str, timeout_s: float = WAIT_S) -> None:
    """Until the view shows a picture other than ``before`` (its image source)."""
    page.wait_for_function("(b) => { const i = document.querySelector('#view img');"
                           " return i && i.src && i.src !== b && i.complete && i.naturalWidth > 0; }",
                           arg=before, timeout=timeout_s * 1e3)


def drawn_fraction(img: np.ndarray, background=(0x1c, 0x1e, 0x24)) -> float:
    """Share of the picture's pixels that are not the view's background."""
    diff = np.abs(img.astype(np.int16) - np.asarray(background, np.int16)).sum(axis=-1)
    return float((diff > 30).mean())


def wait_changed_picture(page, before: np.ndarray, src: str, timeout_s: float = WAIT_S) -> np.ndarray:
    """The first picture the view receives after ``src`` that differs from ``before``
    (VTK may first send its last picture again while it encodes the new one)."""
    import time

    end = time.monotonic() + timeout_s
    while True:
        wait_new_picture(page, src, max(1.0, end - time.monotonic()))
        src, img = picture_src(page), view_picture(page)
        if img.shape != before.shape or changed_fraction(img, before) > 0.001:
            return img
        if time.monotonic() > end:
            raise AssertionError(f"the view's picture did not change in {timeout_s} s")


def changed_fraction(a: np.ndarray, b: np.ndarray) -> float:
    """Share of the pixels that differ between two pictures of one size."""
    return float((np.abs(a.astype(np.int16) - b.astype(np.int16)).sum(axis=-1) > 24).mean())
