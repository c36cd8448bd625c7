"""report.html in a real headless browser at a laptop's width (1366 x 900): the page renders and
opens on its findings; nothing makes the page scroll sideways; a table wider than its place scrolls
inside its own box; no table cell or line of text is cut; every image loads; every in-page link
lands.  Needs Chromium and its driver (Debian: ``apt-get install chromium chromium-driver``) and
selenium (the ``test`` extra); without them the test is skipped, saying so."""
from __future__ import annotations

import copy
import importlib.util
import json
import os
import shutil
from pathlib import Path

import pytest

from freebody.adapters.base import is_available
from freebody.cli import main
from freebody.report.render import write_reports

VIEWPORT = (1366, 900)  # a common laptop screen, CSS pixels
# A layout box may exceed its content box by rounding of fractional CSS pixels (sub-pixel layout).
LAYOUT_SLACK_PX = 1
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
DRIVERS = ("chromedriver",)
NO_BROWSER = "no browser: install chromium and chromium-driver (and selenium, the test extra)"


def _find(names: tuple[str, ...]) -> str | None:
    for name in names:
        path = shutil.which(name) or (f"/usr/bin/{name}" if os.access(f"/usr/bin/{name}", os.X_OK) else None)
        if path:
            return path
    return None


@pytest.fixture(scope="module")
def browser():
    """A headless Chromium at VIEWPORT, or a skip naming what is missing."""
    binary, driver = _find(BROWSERS), _find(DRIVERS)
    if importlib.util.find_spec("selenium") is None or binary is None or driver is None:
        pytest.skip(NO_BROWSER)
    from selenium import webdriver
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service

    options = Options()
    options.binary_location = binary
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                f"--window-size={VIEWPORT[0]},{VIEWPORT[1]}", "--hide-scrollbars"):
        options.add_argument(arg)
    b = webdriver.Chrome(service=Service(driver), options=options)  # a broken browser fails here: not a skip
    try:
        b.set_window_size(*VIEWPORT)
        yield b
    finally:
        b.quit()


@pytest.fixture(scope="module")
def report(tmp_path_factory) -> Path:
    """report.html of a small real run: the Dzhanibekov spin and a 150 rad/s spin at dt = 10 ms
    (PyBullet's per-step rotation cap makes it a finding), on the reference engine and whichever of
    MuJoCo and PyBullet are installed; compared with a baseline whose one run was better."""
    out = tmp_path_factory.mktemp("browser_run")
    engines = ["reference"] + [e for e in ("mujoco", "pybullet") if is_available(e)]
    args = ["run", "dzhanibekov", "high_spin_dt_10ms", "--duration", "1", "--dt", "0.01",
            "--out", str(out), "--quiet", "--no-report", "--jobs", "1"]
    for e in engines:
        args += ["--engine", e]
    assert main(args) == 0
    doc = json.loads((out / "results.json").read_text())
    base = copy.deepcopy(doc)
    ok = [r for r in base["runs"] if r["status"] == "ok"]
    ok[0]["metrics"]["orientation_error_max_rad"] *= 0.5  # the current run is worse: a regression
    write_reports(out, doc, baseline=base)
    return out / "report.html"


# Opens every folded section, then measures in the page; returns the problems found.
CHECKS = r"""
document.querySelectorAll('details').forEach(d => d.open = true);
const vw = document.documentElement.clientWidth;
const out = {scrollWidth: document.documentElement.scrollWidth, viewport: vw, wideTables: [],
             clipped: [], images: [], links: [], ids: []};
function scrollBox(el) {
  for (let p = el.parentElement; p; p = p.parentElement) {
    const o = getComputedStyle(p).overflowX;
    if (o === 'auto' || o === 'scroll') return p;
  }
  return null;
}
document.querySelectorAll('table').forEach((t, i) => {
  const box = scrollBox(t);
  const room = (box || t.parentElement).clientWidth;
  if (t.offsetWidth > room + %(slack)d && !box) out.wideTables.push(i + ': ' + t.offsetWidth + ' > ' + room);
  if (box && box.getBoundingClientRect().right > vw + %(slack)d)
    out.wideTables.push(i + ': its scroll box ends at ' + box.getBoundingClientRect().right);
});
document.querySelectorAll('th, td, p, li, h1, h2, h3, summary, nav, code').forEach(el => {
  if (!el.offsetParent && el.tagName !== 'BODY') return;  // not displayed
  const cut = el.scrollWidth > el.clientWidth + %(slack)d && getComputedStyle(el).overflowX !== 'visible';
  const spill = (el.tagName === 'TD' || el.tagName === 'TH') && el.scrollWidth > el.clientWidth + %(slack)d;
  const off = !scrollBox(el) && el.getBoundingClientRect().right > vw + %(slack)d;
  if (cut || spill || off) out.clipped.push(el.tagName + ': ' + el.textContent.slice(0, 60));
});
document.querySelectorAll('img').forEach(im => {
  if (!im.complete || im.naturalWidth === 0) out.images.push(im.alt);
});
document.querySelectorAll('a[href^="#"]').forEach(a => {
  const id = decodeURIComponent(a.getAttribute('href').slice(1));
  if (!document.getElementById(id)) out.links.push(id);
});
const seen = {};
document.querySelectorAll('[id]').forEach(el => { if (seen[el.id]) out.ids.push(el.id); seen[el.id] = 1; });
return out;
""" % {"slack": LAYOUT_SLACK_PX}


def test_report_renders_readably_at_laptop_width(browser, report, tmp_path):
    browser.get(report.as_uri())
    assert browser.title == "freebody report"
    h2 = [e.text for e in browser.find_elements("css selector", "h2")]
    assert h2[0] == "Findings", h2[:3]  # the verdict first
    assert h2.index("Verdict per case") < h2.index("Engines")
    findings = browser.find_element("css selector", "#findings + p + ul.findings")
    assert "compare verdict" in findings.text and "REGRESSION" in findings.text
    if is_available("pybullet"):
        assert "pybullet/multibody" in findings.text and "high_spin_dt_10ms" in findings.text
    browser.save_screenshot(str(tmp_path / "first_screen.png"))
    got = browser.execute_script(CHECKS)
    assert got["scrollWidth"] <= got["viewport"], "the page scrolls sideways"
    assert got["wideTables"] == [], "tables wider than their place outside a scroll box"
    assert got["clipped"] == [], "text cut or spilling out of its box"
    assert got["images"] == [], "images that did not load"
    assert got["links"] == [] and got["ids"] == [], "in-page links without a target, or duplicate ids"


def test_a_finding_link_opens_its_folded_target(browser, report):
    """A finding's link to its engine's conventions opens the folded section it lands in."""
    if not is_available("pybullet"):
        pytest.skip("pybullet not installed: no finding links to its conventions")
    browser.get(report.as_uri() + "#conventions-pybullet")
    opened = browser.execute_script("return document.getElementById('conventions-pybullet').open")
    assert opened is True


BAD_PAGE = """<!DOCTYPE html><html><head><meta charset="utf-8"><title>bad</title></head><body>
<table><tr><td style="white-space: nowrap">%s</td></tr></table>
<div style="width: 20em"><table><tr><td style="max-width: 5em; overflow: hidden; white-space: nowrap">
a cell whose text is cut at its edge</td></tr></table></div>
<img alt="missing" src="data:image/png;base64,AAAA"><a href="#nowhere">x</a>
<p id="twice">a</p><p id="twice">b</p></body></html>""" % ("a table wider than the page " * 20)


def test_the_checks_see_what_they_look_for(browser, tmp_path):
    """The page checks fail on a page with each fault: a wide table outside a scroll box (the page
    scrolls sideways), a cut cell, a broken image, a link without target, a duplicate id."""
    page = tmp_path / "bad.html"
    page.write_text(BAD_PAGE)
    browser.get(page.as_uri())
    got = browser.execute_script(CHECKS)
    assert got["scrollWidth"] > got["viewport"]
    assert got["wideTables"] and got["clipped"] and got["images"] == ["missing"]
    assert got["links"] == ["nowhere"] and got["ids"] == ["twice"]
