"""The experiment report in a real headless browser (slow; skipped without Chromium/Chrome).

Two checks on a synthetic experiment's report:

* a copy of the page with a small script added is loaded with
  ``--dump-dom``; after the ``load`` event the script records, for every ``<img>``, whether it
  finished loading and decoded to a non-zero size, and the dumped DOM must say all did;
* ``--screenshot`` of the page itself must be a real rendering: a PNG of the window size
  whose pixels vary (not a blank or error page).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from headless import CHROMIUMS, find_chromium, run_chromium
from synthetic_data import FakeMethods, blend, make_render_folder, write_spec

from mcdenoise.experiments import load_experiment, run_experiment

CHECK = """
<script>
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) {
    return !(i.complete && i.naturalWidth > 0 && i.naturalHeight > 0);
  });
  var out = document.createElement("pre");
  out.id = "imgcheck";
  out.textContent = "IMAGES " + imgs.length + " DECODED " + (imgs.length - bad.length) +
    " BROKEN " + bad.map(function (i) { return i.getAttribute("src"); }).join(",");
  document.body.appendChild(out);
});
</script>
"""


@pytest.fixture(scope="module")
def report_dir(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("browser")
    make_render_folder(tmp / "rendered", size=(24, 32), spp=(1, 2, 4, 8))
    spec = write_spec(
        tmp / "exp.toml",
        'methods = ["box", "soft"]\nmetrics = ["relmse", "psnr"]\nrepetitions = 1\nwarmup = 0\n'
        '[scenes]\nfolder = "rendered"\n',
    )
    with pytest.MonkeyPatch.context() as mp:
        fake = FakeMethods(mp)
        fake.add("box", blend)
        fake.add("soft", blend, defaults={"strength": 0.5})
        run_experiment(load_experiment(spec), tmp / "out")
    return tmp / "out"


@pytest.mark.slow
def test_every_image_and_plot_loads_and_decodes_in_a_browser(report_dir: Path, tmp_path: Path):
    exe = find_chromium()
    if exe is None:
        pytest.skip(f"no headless browser found ({', '.join(CHROMIUMS)})")
    page = (report_dir / "report.html").read_text(encoding="utf-8")
    expected = len(re.findall(r"<img\b", page))
    assert expected >= 20
    check = report_dir / "check.html"  # same folder: the relative image paths resolve
    check.write_text(page.replace("</body>", CHECK + "</body>"), encoding="utf-8")
    done = run_chromium(
        exe, tmp_path / "profile", "--virtual-time-budget=10000", "--dump-dom", check.as_uri()
    )
    assert done.returncode == 0, done.stderr[-2000:]
    m = re.search(r"IMAGES (\d+) DECODED (\d+) BROKEN ([^<]*)", done.stdout)
    assert m is not None, "the page's load event never ran: " + done.stdout[-500:]
    total, decoded, broken = int(m.group(1)), int(m.group(2)), m.group(3).strip()
    assert total == expected and decoded == total, f"broken images: {broken}"


@pytest.mark.slow
def test_screenshot_of_the_report_is_not_blank(report_dir: Path, tmp_path: Path):
    import OpenImageIO as oiio

    exe = find_chromium()
    if exe is None:
        pytest.skip(f"no headless browser found ({', '.join(CHROMIUMS)})")
    shot = tmp_path / "shot.png"
    done = run_chromium(
        exe,
        tmp_path / "profile",
        "--window-size=1200,2400",
        f"--screenshot={shot}",
        (report_dir / "report.html").as_uri(),
    )
    assert done.returncode == 0 and shot.is_file(), done.stderr[-2000:]
    pixels = oiio.ImageBuf(str(shot)).get_pixels(oiio.FLOAT)
    assert pixels.shape[:2] == (2400, 1200)
    # text, tables and plots: many distinct grey levels, a good share of non-white pixels
    luminance = pixels[..., :3].mean(axis=-1)
    assert float(np.std(luminance)) > 0.05
    assert float((luminance < 0.9).mean()) > 0.03
    assert len(np.unique(np.round(luminance, 2))) > 20
