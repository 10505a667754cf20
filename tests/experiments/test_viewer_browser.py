"""The report's interactive viewer in a real headless browser (Debian's ``chromium``).

The report of ``synthetic_viewer.py``'s experiment (outputs kept at the strip level only, so
other levels are "not available"; a method that cannot run; NaN pixels in a noisy input) is
opened from ``file://`` with ``#viewer-selftest``: the viewer's script zooms with a wheel
event, moves the exposure slider, presses ``e``, then clicks through every image in every
view, and writes what the canvas showed into ``<pre id="viewer-selftest">``, which
``--dump-dom`` returns. Screenshots of the viewer must show images, and single pixels at high
zoom as flat blocks (nearest neighbour). A sequence's report has a frame slider.

Without Chromium the tests are skipped, except where ``CI`` is set: there a missing browser
fails them (``make browser-deps`` installs it). Firefox, where installed (Debian's
``firefox-esr``; not in CI), runs the same self-test: it prints the result on its console.
"""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from headless import chromium, run_chromium
from synthetic_viewer import SIZE, run_sequence_experiment, run_viewer_experiment

FIREFOXES = ("firefox", "firefox-esr")
WIDTH = 1400


#: What every self-test run adds: the page's console on stderr, and time for the data to decode.
LOGGED = ("--enable-logging=stderr", "--v=0", "--virtual-time-budget=10000")


def selftest(exe: str, page: Path, profile: Path) -> tuple[dict[str, Any], str, str]:
    """The self-test's JSON, Chromium's log and the page's DOM after the self-test."""
    done = run_chromium(
        exe,
        profile,
        *LOGGED,
        f"--window-size={WIDTH},1000",
        "--dump-dom",
        page.as_uri() + "#viewer-selftest",
    )
    assert done.returncode == 0, done.stderr[-2000:]
    m = re.search(r'<pre id="viewer-selftest">([^<]*)</pre>', done.stdout)
    assert m is not None, "the self-test wrote nothing: " + done.stdout[-1000:]
    return json.loads(html.unescape(m.group(1))), done.stderr, done.stdout


def page_errors(log: str) -> list[str]:
    """Uncaught exceptions and console messages of the page in Chromium's log."""
    return [
        line
        for line in log.splitlines()
        if ("Uncaught" in line or (":CONSOLE" in line and "file://" in line))
        and '"viewer-selftest {' not in line  # the self-test's own result line
    ]


def screenshot(exe: str, url: str, height: int, profile: Path) -> np.ndarray:
    """A screenshot of the whole page (``height`` px tall) as ``(H, W, 3)`` uint8.

    Headless Chromium's ``--screenshot`` captures a blank page once the page is scrolled (an
    anchor such as ``#viewer-0`` scrolls it), so the window is as tall as the page and the
    viewer is cut out of the picture at the place the self-test measured.
    """
    import OpenImageIO as oiio

    shot = profile.parent / f"{profile.name}.png"
    done = run_chromium(
        exe, profile, *LOGGED, f"--window-size={WIDTH},{height}", f"--screenshot={shot}", url
    )
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    return oiio.ImageBuf(str(shot)).get_pixels(oiio.UINT8)[..., :3]


def cut(image: np.ndarray, rect: dict[str, int]) -> np.ndarray:
    return image[rect["y"] : rect["y"] + rect["h"], rect["x"] : rect["x"] + rect["w"]]


def colours(image: np.ndarray) -> int:
    return len(np.unique(image.reshape(-1, 3), axis=0))


def is_pane(image: np.ndarray) -> bool:
    """``image`` is cut exactly around a pane: its 1-pixel border is #777 all round."""
    edges = np.concatenate([image[0], image[-1], image[:, 0], image[:, -1]])
    return bool((edges == 0x77).all())


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    out, _ = run_viewer_experiment(tmp_path_factory.mktemp("viewer-browser"), outputs="strip")
    return out / "report.html"


@pytest.fixture(scope="module")
def tested(report, tmp_path_factory) -> tuple[dict[str, Any], str]:
    result, log, _ = selftest(chromium(), report, tmp_path_factory.mktemp("profile"))
    return result, log


def test_the_selftest_zooms_and_changes_the_exposure_without_an_error(tested):
    result, log = tested
    assert result["errors"] == [] and page_errors(log) == []
    assert result["viewers"] == 2
    # every stored colour layer decoded: noisy, box, soft, odd at 4 spp, noisy at 1, reference
    assert result["images"] == result["decoded"] == 2 * 6
    assert result["flip_layers"] > 0  # the FLIP view was shown (flip_evaluator is installed)
    # the wheel event zoomed 4x about the centre: the canvas changed
    assert result["zoom_after"] == pytest.approx(4 * result["zoom_before"])
    assert result["after_zoom"]["hash"] != result["before"]["hash"]
    # +2 EV brightens, the error view shows something else again
    assert result["after_exposure"]["mean"] > result["after_zoom"]["mean"] + 10
    assert result["view"] == "relmse"
    assert result["after_error_view"]["hash"] != result["after_exposure"]["hash"]


def test_missing_outputs_and_nan_pixels_show_as_such(tested):
    """docs/hard-cases.md item 75: an output not kept, a method that could not run, NaN
    pixels in a noisy input: named "not available" with the reason, or drawn magenta and
    counted; no error on the page."""
    result, log = tested
    shown = result["shown"]
    assert shown["image:box@4"] == "shown, 0 NaN/Inf"
    assert shown["image:box@1"].startswith("box at 1 spp: not available (output not kept")
    assert "could not run" in shown["image:refuse@4"]
    assert shown["image:noisy@4"] == "shown, 4 NaN/Inf"  # alpha's 2×2 NaN block
    assert shown["relmse:noisy@4"] == "shown, 4 NaN/Inf"
    assert shown["flip:noisy@4"] == "shown, 4 NaN/Inf"  # no FLIP map: the image instead
    assert shown["flip:box@4"] == "shown, 0 NaN/Inf"
    assert result["errors"] == [] and page_errors(log) == []


def bottom(result: dict[str, Any]) -> int:
    """The window height that holds the first viewer (the page above it included)."""
    return result["rect"]["y"] + result["rect"]["h"] + 10


def test_a_screenshot_of_the_viewer_shows_images(report, tested, tmp_path):
    result, _ = tested
    page = screenshot(chromium(), report.as_uri(), bottom(result), tmp_path / "open")
    viewer = cut(page, result["rect"])
    assert viewer.shape[:2] == (result["rect"]["h"], result["rect"]["w"])
    assert colours(viewer) > 300  # text, buttons and two images, not a blank area
    pane = cut(page, result["pane"])
    assert is_pane(pane)  # the viewer loaded and drew its panes where the self-test saw them
    assert colours(pane) > 200 and pane.astype(np.float64).std() > 10


def test_zoomed_in_single_pixels_are_flat_blocks(report, tested, tmp_path):
    """After the self-test the view is zoomed 4x past fitting; nearest neighbour draws each
    image pixel as a flat block, so the pane holds about as many colours as image pixels in
    view (smoothing would blend thousands)."""
    result, _ = tested
    url = report.as_uri() + "#viewer-selftest"
    page = screenshot(chromium(), url, bottom(result), tmp_path / "zoomed")
    pane = cut(page, result["pane"])
    assert is_pane(pane)
    pane = pane[2:-2, 2:-2]  # inside the border
    zoom = result["zoom_after"]
    in_view = (pane.shape[0] / zoom + 2) * (pane.shape[1] / zoom + 2)
    assert zoom > 20 and pane.shape[1] / zoom < SIZE[1]
    assert 4 <= colours(pane) <= 1.2 * in_view


def test_a_sequence_has_a_frame_slider_and_no_error(tmp_path, fake_methods):
    exe = chromium()
    run_sequence_experiment(tmp_path, fake_methods)
    result, log, dom = selftest(exe, tmp_path / "out" / "report.html", tmp_path / "profile")
    assert result["errors"] == [] and page_errors(log) == []
    assert result["images"] == result["decoded"] == 3 * (2 * 2 + 1)  # noisy, box; reference
    # the frame slider, at the middle frame
    assert re.search(r'<input type="range" min="0" max="2" step="1" value="1"', dom)


def firefox_selftest(exe: str, page: Path, profile: Path, timeout: float = 90.0) -> dict:
    """The self-test's JSON from headless Firefox, which has no ``--dump-dom``: the profile's
    ``devtools.console.stdout.content`` prints the page's console on stdout, where the self-test
    logs its result (``viewer-selftest {json}``); Firefox is stopped once it has."""
    profile.mkdir(parents=True, exist_ok=True)
    (profile / "user.js").write_text(
        'user_pref("devtools.console.stdout.content", true);\n'
        'user_pref("browser.shell.checkDefaultBrowser", false);\n',
        encoding="utf-8",
    )
    cmd = [exe, "--headless", "--no-remote", "--profile", str(profile)]
    proc = subprocess.Popen(
        [*cmd, f"--window-size={WIDTH},1000", page.as_uri() + "#viewer-selftest"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    found: dict | None = None
    deadline = time.monotonic() + timeout
    try:
        assert proc.stdout is not None
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            # console.log: "viewer-selftest {\"viewers\":2,...}" (the string as a JS literal)
            m = re.search(r'"viewer-selftest (\{.*\})"\s*$', line)
            if m:
                found = json.loads(json.loads(f'"{m.group(1)}"'))
                break
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert found is not None, "Firefox printed no self-test: " + "".join(lines)[-2000:]
    found["log"] = "".join(lines)
    return found


def test_the_viewer_runs_its_selftest_in_firefox(report, tmp_path):
    exe = next((p for p in map(shutil.which, FIREFOXES) if p), None)
    if exe is None:
        pytest.skip(f"no Firefox ({', '.join(FIREFOXES)})")
    result = firefox_selftest(exe, report, tmp_path / "firefox")
    assert result["errors"] == [], result["log"][-2000:]
    assert result["images"] == result["decoded"] == 2 * 6
    assert result["zoom_after"] == pytest.approx(4 * result["zoom_before"])
    assert result["after_zoom"]["hash"] != result["before"]["hash"]
    assert result["after_exposure"]["mean"] > result["after_zoom"]["mean"] + 10
    assert result["after_error_view"]["hash"] != result["after_exposure"]["hash"]
