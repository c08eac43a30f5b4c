"""``report.html`` as a person looks at it: opened in headless Chromium, every picture decoded and laid out at
its size, every figure on the page and visible in a screenshot, and the page printed to a PDF. Runs where
Chromium is installed (``apt-get install chromium``; CI installs it); skips with the reason elsewhere."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from stereogeo_cli.cli import app

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
WIDTH = 1280  # the window's width in CSS pixels
PAIR_FIGURES = ["result", "gravity-fields", "rectified", "row-errors", "coverage", "focal-evidence"]

# What the page shows once loaded, written into the page for --dump-dom to carry out (the report itself has
# no script: this copy only measures it)
MEASURE = """<script>
window.addEventListener("load", () => {
  const box = (e) => { const r = e.getBoundingClientRect();
                       return {top: r.top + window.scrollY, left: r.left + window.scrollX, width: r.width,
                               height: r.height}; };
  const out = {height: document.documentElement.scrollHeight, images: [], figures: []};
  for (const img of document.images) {
    out.images.push({alt: img.alt, complete: img.complete, naturalWidth: img.naturalWidth,
                     naturalHeight: img.naturalHeight, width: +img.getAttribute("width"),
                     height: +img.getAttribute("height"), shown: box(img)});
  }
  for (const f of document.querySelectorAll("figure[data-figure]")) {
    out.figures.push({name: f.dataset.figure, ...box(f)});
  }
  const pre = document.createElement("pre");
  pre.id = "measured";
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def _browser() -> str:
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    pytest.skip(
        "Chromium is not installed (apt-get install chromium): report.html is not looked at in a browser"
    )


def _run(browser: str, *args: str, timeout: int = 120) -> subprocess.CompletedProcess:
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
             "--disable-dev-shm-usage", "--run-all-compositor-stages-before-draw"]  # fmt: skip
    done = subprocess.run([browser, *flags, *args], capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stderr[-2000:]
    return done


@pytest.fixture(scope="module")
def page(example_pair, onnx_model, tmp_path_factory) -> dict:
    """The example pair's report.html, and what Chromium measured of it once loaded."""
    browser = _browser()
    folder = tmp_path_factory.mktemp("browser")
    out = folder / "out"
    result = CliRunner().invoke(app, ["calibrate", *map(str, example_pair), "--model", str(onnx_model), "-o",
                                      str(out), "--format", "json,html"])  # fmt: skip
    assert result.exit_code == 0, result.output
    measured = folder / "measured.html"
    measured.write_text(
        (out / "report.html").read_text(encoding="utf-8").replace("</body>", MEASURE + "</body>")
    )
    dom = _run(browser, "--virtual-time-budget=10000", f"--window-size={WIDTH},1000", "--dump-dom",
               measured.as_uri()).stdout  # fmt: skip
    found = re.search(r'<pre id="measured">(.*?)</pre>', dom, re.S)
    assert found, "the page did not finish loading"
    return {"browser": browser, "folder": folder, "report": out / "report.html",
            "measured": json.loads(html.unescape(found.group(1)))}  # fmt: skip


def test_every_picture_is_decoded_and_shown_at_its_size(page):
    images = page["measured"]["images"]
    assert len(images) >= 20
    for image in images:
        assert image["complete"] and image["naturalWidth"] > 0, image["alt"]
        natural = (image["naturalWidth"], image["naturalHeight"])
        assert natural == (image["width"], image["height"]), image["alt"]
        shown = image["shown"]
        assert shown["width"] > 0 and shown["height"] > 0, image["alt"]
        # laid out at its own shape (no picture squashed), within the page
        ratio = (shown["width"] / shown["height"]) / (image["width"] / image["height"])
        assert abs(ratio - 1) < 0.05, (image["alt"], ratio)
        assert shown["width"] <= WIDTH, image["alt"]


def test_every_figure_is_on_the_page_and_visible_in_a_screenshot(page):
    measured = page["measured"]
    figures = measured["figures"]
    assert [f["name"] for f in figures] == PAIR_FIGURES
    height = int(measured["height"])
    shot = page["folder"] / "shot.png"
    _run(page["browser"], f"--window-size={WIDTH},{height}", f"--screenshot={shot}", page["report"].as_uri())
    picture = np.asarray(Image.open(shot).convert("RGB"))
    assert picture.shape[:2] == (height, WIDTH)
    grey = picture.mean(axis=2)
    assert grey.std() > 30, "the page is blank"
    for figure in figures:
        assert figure["height"] > 60 and figure["width"] > 600, figure
        top, bottom = int(figure["top"]), int(figure["top"] + figure["height"])
        band = picture[top:bottom]
        drawn = np.abs(band.astype(int) - 255).sum(axis=2) > 30  # not the white page
        assert drawn.mean() > 0.03, f"{figure['name']} shows nothing in the screenshot"
    for image in measured["images"]:  # each picture painted where the page put it
        shown = image["shown"]
        if shown["width"] * shown["height"] < 2000:  # the colour bars
            continue
        top, left = int(shown["top"]), int(shown["left"])
        area = picture[top : top + int(shown["height"]), left : left + int(shown["width"])]
        assert area.size and area.std() > 10, f"{image['alt']} is not painted"


def test_the_page_prints_to_a_pdf(page):
    pdf = page["folder"] / "report.pdf"
    _run(page["browser"], "--no-pdf-header-footer", f"--print-to-pdf={pdf}", page["report"].as_uri())
    data = pdf.read_bytes()
    assert data.startswith(b"%PDF") and len(data) > 100_000  # the pictures are in it
    pages = len(re.findall(rb"/Type\s*/Page[^s]", data))
    assert 2 <= pages <= 12, pages
