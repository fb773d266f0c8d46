"""Headless Chromium renders the meshcat page of a live simulate_chain.py run and its HTML replay; the
screenshots must show the scene (table wood) and the chain status display (the active stage's red cube).

Chromium comes from Debian (``apt-get install -y chromium``; ``.ci/run`` installs it). Without it this test
fails: a browser check that silently skips checks nothing.
"""

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "simulate_chain.py"
LIVE_WAIT = "--virtual-time-budget=5000"
REPLAY_WAIT = "--timeout=15000"


def chromium() -> str:
    path = shutil.which("chromium") or shutil.which("chromium-browser")
    if path is None:
        pytest.fail("chromium is not installed; install it with: apt-get install -y chromium (see .ci/run)")
    return path


def screenshot(url: str, out: Path, wait: str, attempts: int = 3) -> np.ndarray:
    """A 1024 x 768 screenshot of ``url``, taken after ``wait`` (a Chromium flag), retried on a hang.

    The live page fills in over its websocket after the page has loaded, so it needs virtual time
    (``--virtual-time-budget``). The HTML replay carries its scene inline, and under virtual time Chromium
    hung on it in most tries (the page plays its recording forever); ``--timeout`` screenshots it once loaded.
    """
    for _ in range(attempts):
        out.unlink(missing_ok=True)
        command = [chromium(), "--headless", "--no-sandbox", "--disable-gpu", "--enable-unsafe-swiftshader",
                   "--disable-quic", "--no-first-run", "--disable-background-networking", "--disable-component-update",
                   "--disable-sync", f"--user-data-dir={tempfile.mkdtemp()}", "--window-size=1024,768",
                   wait, f"--screenshot={out}", url]
        try:
            subprocess.run(command, capture_output=True, timeout=60)
        except subprocess.TimeoutExpired:
            continue
        if out.is_file() and out.stat().st_size > 0:
            return np.asarray(Image.open(out).convert("RGB")).astype(int)
    pytest.fail(f"chromium produced no screenshot of {url} in {attempts} attempts")


def scene_pixels(image: np.ndarray) -> dict:
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    return {
        # The table top (0.60, 0.42, 0.24) under meshcat's lights: orange-brown.
        "table": int(np.sum((r > 90) & (r - g > 25) & (g - b > 20) & (r < 250))),
        # The running stage's cube (0.95, 0.15, 0.15): saturated red.
        "active_stage": int(np.sum((r > 150) & (g < 80) & (b < 80))),
    }


def check_rendered(image: np.ndarray, where: str) -> None:
    counts = scene_pixels(image)
    assert image.std() > 10, f"{where}: the screenshot is blank"
    assert counts["table"] > 5000, f"{where}: no table in the picture ({counts})"
    assert counts["active_stage"] > 40, f"{where}: no active-stage cube in the picture ({counts})"


def test_live_page_and_replay_render(tmp_path):
    replay = tmp_path / "replay.html"
    process = subprocess.Popen(
        [sys.executable, str(SCRIPT), "--task", "tool_positioning", "--duration", "0.5", "--port", "7240",
         "--record", str(replay)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO)
    url, lines = None, []
    try:
        deadline = time.monotonic() + 180
        for line in process.stdout:
            lines.append(line)
            if line.startswith("meshcat: open "):
                url = line.split()[2]
            if "keeps serving" in line or time.monotonic() > deadline:
                break
        assert url is not None and replay.is_file(), "".join(lines)
        check_rendered(screenshot(url, tmp_path / "live.png", LIVE_WAIT), "live meshcat page")
    finally:
        process.send_signal(signal.SIGINT)
        try:
            process.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.kill(process.pid, signal.SIGKILL)
    assert process.returncode == 0, "".join(lines)
    check_rendered(screenshot(replay.as_uri(), tmp_path / "replay.png", REPLAY_WAIT), "HTML replay")
