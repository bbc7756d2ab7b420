"""The documentation site as a reader sees it at 1,280 px, in headless Chromium: the site is built (`mkdocs build
--strict`), the home page and ToyTown's state page are screenshotted, and a probe run in the page after it loads
reads the layout: every figure is a link to itself and shown at a readable scale on the home page, the home page and
the results index hold a driving section, and the driving table's key columns are in view with the rest scrolling
in the table's own box, its first column held.

Skipped where Chromium is not installed (CI installs Debian's `chromium`: `.ci/run`)."""

import html
import json
import os
import pathlib
import re
import shutil
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
WIDTH = 1280
# The key columns of a driving table, which must show without horizontal scrolling.
KEY_COLUMNS = ["method", "success %", "collisions", "stuck %", "copycat: first verdict", "copycat: controlled verdict"]
# Run in the page after it loads: what the layout shows, as JSON in the body's `data-probe`.
PROBE = """<script>
window.addEventListener("load", () => {
  const article = document.querySelector("article");
  const images = [...article.querySelectorAll("img")];
  const linked = images.filter(i => { const a = i.closest("a"); return a !== null && a.href === i.src; });
  const out = {images: images.map(i => i.getAttribute("src")), linked: linked.length,
               scales: images.map(i => i.getBoundingClientRect().width / i.naturalWidth)};
  const table = article.querySelector("table");
  if (table) {
    const right = Math.min(table.getBoundingClientRect().right, article.getBoundingClientRect().right);
    const heads = [...table.querySelectorAll("thead th")];
    out.columns = heads.map(th => th.textContent.trim().replace(/\\s+/g, " "));
    out.shown = heads.filter(th => th.getBoundingClientRect().right <= right + 1).map(
      th => th.textContent.trim().replace(/\\s+/g, " "));
    out.sticky = getComputedStyle(heads[0]).position;
    const left = heads[0].getBoundingClientRect().left;
    table.scrollLeft = table.scrollWidth;
    out.scrolled = table.scrollLeft;
    out.held = Math.abs(heads[0].getBoundingClientRect().left - left) < 1;
  }
  document.body.setAttribute("data-probe", JSON.stringify(out));
});
</script>"""

pytestmark = pytest.mark.integration


def _chromium() -> str:
    found = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)
    if found is None:
        pytest.skip("Chromium is not installed (Debian: apt-get install chromium): the site's screenshots need it")
    return found


def _run(browser: str, *args: str) -> str:
    out = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                          f"--window-size={WIDTH},2000", *args], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> pathlib.Path:
    """The site, built with `mkdocs build --strict` as CI builds it."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    _chromium()
    out = tmp_path_factory.mktemp("site")
    built = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(out)], cwd=ROOT,
                           capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"}, timeout=300)
    assert built.returncode == 0, built.stderr[-2000:]
    return out


def _probe(site: pathlib.Path, page: str) -> dict:
    """`PROBE`'s findings on `page` (a path in the site), read from the DOM Chromium dumps."""
    path = site / page
    probed = path.with_name("probe.html")
    probed.write_text(path.read_text().replace("</body>", PROBE + "</body>"))
    found = re.search(r'data-probe="([^"]*)"', _run(_chromium(), "--dump-dom", probed.as_uri()))
    assert found, f"the probe did not run on {page}"
    return json.loads(html.unescape(found.group(1)))


def _screenshot(site: pathlib.Path, page: str, out: pathlib.Path) -> None:
    from PIL import Image

    _run(_chromium(), f"--screenshot={out}", (site / page).as_uri())
    with Image.open(out) as im:
        assert im.size[0] == WIDTH
        assert len(im.convert("L").getcolors()) > 16   # drawn: text and figures, not a blank page


def _driving_section(page: str, anchor: str) -> str:
    """The HTML of the `<h2>` with id `anchor` up to the next `<h2`."""
    start = page.index(f'<h2 id="{anchor}"')
    end = page.find("<h2", start + 1)
    return page[start:end if end >= 0 else None]


def test_the_home_page_shows_driving_and_readable_figures_that_open_full_size(site, tmp_path):
    _screenshot(site, "index.html", tmp_path / "home.png")
    found = _probe(site, "index.html")
    assert found["images"] and found["linked"] == len(found["images"])   # every figure a link to itself
    assert min(found["scales"]) >= 0.5, found["scales"]   # not shrunk past reading at 1,280 px
    driving = _driving_section((site / "index.html").read_text(), "driving")
    assert re.search(r'<img [^>]*src="[^"]*figures/driving-toytown-[^"]*\.png"', driving)
    assert 'href="results/toytown-pos/' in driving and 'href="results/toytown-image/' in driving


def test_the_results_index_has_a_driving_section(site):
    driving = _driving_section((site / "results" / "index.html").read_text(), "driving-toytown")
    assert re.search(r'<a href="[^"]*figures/driving-toytown-[^"]*\.png" class="full-size"><img ', driving)
    assert 'href="toytown-pos/"' in driving and 'href="toytown-image/"' in driving


def test_a_driving_tables_key_columns_are_in_view_and_the_rest_scrolls_beside_the_held_method(site, tmp_path):
    page = "results/toytown-pos/index.html"
    _screenshot(site, page, tmp_path / "toytown-pos.png")
    found = _probe(site, page)
    assert found["columns"][:len(KEY_COLUMNS)] == KEY_COLUMNS
    assert set(KEY_COLUMNS) <= set(found["shown"]), found["shown"]
    assert found["linked"] == len(found["images"]) > 0
    # the table is wider than the column: it scrolls in its own box, and its first column stays put
    assert len(found["shown"]) < len(found["columns"]) and found["scrolled"] > 0
    assert found["sticky"] == "sticky" and found["held"]
