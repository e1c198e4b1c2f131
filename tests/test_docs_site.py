"""The documentation site (issue 34, item 2): built offline and strict, checked in a browser.

``mkdocs build --strict`` builds the site into a temporary directory (a broken link, a
reference that does not resolve or a docstring that does not parse fails it); then the built
pages are opened in headless Chromium (Debian's ``chromium``; ``.ci/run`` installs it) and
their rendered DOM is read back: equations typeset by the vendored KaTeX, images loaded,
API signatures present, on the home page, an API page and a notebook page.

The pages are opened as copies with one script appended (``index.check.html`` next to
``index.html``, so every relative URL is the page's own) that waits for the page to load and
writes what it finds into the DOM, which ``chromium --dump-dom`` prints.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mkdocs")

ROOT = Path(__file__).resolve().parents[1]
BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
EXTERNAL = re.compile(r"""<(?:script|link|img|iframe)\b[^>]*\b(?:src|href)=["']?(?:https?:)?//""")
CHECK = """<script>
window.addEventListener("load", () => setTimeout(() => {
  const text = (sel) => [...document.querySelectorAll(sel)].map((e) => e.textContent.trim());
  const images = [...document.querySelectorAll(".md-content img")];
  const math = [...document.querySelectorAll(".arithmatex")];
  const found = {
    katex: document.querySelectorAll(".katex").length,
    katex_errors: document.querySelectorAll(".katex-error").length,
    math: math.length,
    math_untypeset: math.filter((e) => !e.querySelector(".katex")).length,
    images: images.map((i) => ({src: i.getAttribute("src").slice(0, 60),
                                complete: i.complete, width: i.naturalWidth})),
    signatures: text(".doc-signature"),
    headings: [...document.querySelectorAll(".doc-heading")].map((e) => e.id),
  };
  const out = document.createElement("pre");
  out.id = "wfjax-check";
  out.textContent = JSON.stringify(found);
  document.body.appendChild(out);
}, 1000));
</script>
"""


def _browser() -> str | None:
    return next((path for name in BROWSERS if (path := shutil.which(name))), None)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site, built with ``--strict`` into a temporary directory (not into the tree)."""
    out = tmp_path_factory.mktemp("site")
    work = tmp_path_factory.mktemp("mkdocs-cwd")
    before = {p for p in (ROOT / "docs").rglob("*")} | {p for p in ROOT.iterdir()}
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict",
                           "--config-file", ROOT / "mkdocs.yml", "--site-dir", out],
                          cwd=work, capture_output=True, text=True, timeout=600,
                          env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    after = {p for p in (ROOT / "docs").rglob("*")} | {p for p in ROOT.iterdir()}
    assert not after - before, f"the build wrote into the source tree: {after - before}"
    assert not list(work.iterdir())
    return out


def test_every_page_is_built(site):
    for page in ("index.html", "getting_started/index.html", "case_files/index.html",
                 "vehicle/index.html", "api/index.html", "api/fit/index.html",
                 "api/model/index.html", "api/contact/index.html", "benchmarks/index.html",
                 "reproduction/index.html", "changelog/index.html"):
        assert (site / page).is_file(), page
    for notebook in (ROOT / "notebooks").glob("*.ipynb"):
        assert (site / "notebooks" / notebook.stem / "index.html").is_file(), notebook.name
    api = (site / "api" / "index.html").read_text()
    assert "<code>wfjax.Flat</code>" in api and ":class:<code>" not in api  # roles rendered


def test_included_pages_carry_their_source(site):
    """The benchmark headline and the changelog come from their one source file."""
    bench = (site / "benchmarks" / "index.html").read_text()
    assert "NumPy/SciPy baseline" in bench and "<table>" in bench
    assert "<!-- include:" not in bench
    assert "Unreleased" in (site / "changelog" / "index.html").read_text()
    reproduction = (site / "reproduction" / "index.html").read_text()
    for figure in ("fig5_inputs.png", "fig7_speed_sweep.png", "fig8_depths.png"):
        assert f'src="../figures/{figure}"' in reproduction
        assert (site / "figures" / figure).stat().st_size > 10_000


def test_pages_load_nothing_from_the_network(site):
    """Offline: no script, style sheet, font or image from another host."""
    for page in site.rglob("*.html"):
        assert not EXTERNAL.search(page.read_text()), page
    for css in site.rglob("*.css"):
        assert not re.search(r"url\(\s*['\"]?(https?:)?//", css.read_text()), css
    assert (site / "assets" / "katex" / "katex.min.js").is_file()


def _rendered(site: Path, page: str, browser: str) -> dict:
    """What the check script found in ``page`` once Chromium has rendered it."""
    source = site / page
    checked = source.with_name(source.stem + ".check.html")
    checked.write_text(source.read_text().replace("</body>", CHECK + "</body>"))
    proc = subprocess.run([browser, "--headless", "--no-sandbox", "--disable-gpu",
                           "--allow-file-access-from-files", "--virtual-time-budget=20000",
                           "--dump-dom", checked.as_uri()],
                          capture_output=True, text=True, timeout=120)
    found = re.search(r'<pre id="wfjax-check">(.*?)</pre>', proc.stdout, re.S)
    assert found, f"{page}: no check result (exit {proc.returncode})\n{proc.stderr[-2000:]}"
    return json.loads(found.group(1).replace("&quot;", '"').replace("&amp;", "&")
                      .replace("&lt;", "<").replace("&gt;", ">"))


@pytest.fixture(scope="module")
def browser() -> str:
    path = _browser()
    if path is None:
        if os.environ.get("CI"):
            pytest.fail("no Chromium: .ci/run installs Debian's chromium (apt-get)")
        pytest.skip("no Chromium (apt-get install chromium) for the rendered-page checks")
    return path


def test_home_page_typesets_its_equations_and_loads_its_image(site, browser):
    found = _rendered(site, "index.html", browser)
    assert found["math"] >= 5 and found["math_untypeset"] == 0, found
    assert found["katex"] >= found["math"] and found["katex_errors"] == 0, found
    assert found["images"] and all(i["complete"] and i["width"] > 0
                                   for i in found["images"]), found["images"]


def test_api_page_shows_the_signatures(site, browser):
    found = _rendered(site, "api/index.html", browser)
    signatures = " ".join(found["signatures"])
    for name, parameter in (("simulate", "speed"), ("sweep", "impact_positions")):
        assert re.search(rf"\b{name}\(", signatures), name
        assert parameter in signatures
    assert {"wfjax.simulate", "wfjax.sweep", "wfjax.Scenario"} <= set(found["headings"])


def test_notebook_page_shows_its_stored_figures(site, browser):
    found = _rendered(site, "notebooks/quickstart/index.html", browser)
    outputs = [i for i in found["images"] if i["src"].startswith("data:image/png")]
    assert outputs and all(i["complete"] and i["width"] > 0 for i in outputs), found["images"]
