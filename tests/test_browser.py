"""End-to-end: the dashboard served by ``streamlit run`` and opened in headless Chromium (Playwright).

Needs the ``playwright`` Python package and Debian's ``chromium`` (``apt-get install chromium``:
/usr/bin/chromium); ``playwright install`` is not used. Skipped with the reason when either is
missing. Saves screenshots to the test's tmp dir and once to /tmp/dashboard.png (learning curves)
and /tmp/dashboard_table1.png.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from tests.fixtures_results import write_big, write_fixture

ROOT = Path(__file__).resolve().parent.parent
CHROMIUM = os.environ.get("HARNESS_CHROMIUM", "/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]

try:
    import playwright.sync_api  # noqa: F401

    HAVE_PLAYWRIGHT = True
except ImportError:
    HAVE_PLAYWRIGHT = False

pytestmark = [
    pytest.mark.skipif(not HAVE_PLAYWRIGHT, reason="playwright (pip install playwright) is not installed"),
    pytest.mark.skipif(not (Path(CHROMIUM).exists() or shutil.which("chromium")),
                       reason=f"chromium not found at {CHROMIUM} (apt-get install chromium)"),
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(results: Path, log_path: Path):
    """``streamlit run app.py`` on ``results`` at a free port; yields the URL."""
    port = free_port()
    log = open(log_path, "w")
    env = {**os.environ, "HARNESS_RESULTS": str(results)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "streamlit", "run", str(ROOT / "app.py"), "--server.headless", "true",
         "--server.port", str(port), "--server.address", "127.0.0.1", "--browser.gatherUsageStats", "false",
         "--server.fileWatcherType", "none", "--", "--results", str(results)],
        cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 60
        while True:
            try:
                if urllib.request.urlopen(url + "/_stcore/health", timeout=2).status == 200:
                    break
            except OSError:
                pass
            if proc.poll() is not None or time.time() > deadline:
                log.flush()
                pytest.fail("streamlit did not start: " + log_path.read_text()[-2000:])
            time.sleep(0.2)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
        log.close()


@contextlib.contextmanager
def chromium():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM if Path(CHROMIUM).exists() else shutil.which("chromium"),
                                    args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


@pytest.fixture
def server(tmp_path):
    with serve(write_fixture(tmp_path / "results", failed=False), tmp_path / "streamlit.log") as url:
        yield url


def _no_exception(page) -> None:
    text = page.inner_text("body")
    assert "Traceback" not in text and "Error" not in text, text[:2000]
    assert page.locator('[data-testid="stException"]').count() == 0


def test_dashboard_in_chromium(server, tmp_path):
    with chromium() as browser:
        page = browser.new_page(viewport={"width": 1500, "height": 1100})
        t0 = time.perf_counter()
        page.goto(server, wait_until="domcontentloaded")
        page.get_by_text("Reset-free RL on EARL: results").wait_for(timeout=30_000)
        page.locator('[data-testid="stMetric"]').first.wait_for(timeout=30_000)  # Runs tab: state counts
        print(f"\nbrowser: main page (Runs) rendered in {time.perf_counter() - t0:.2f} s")
        _no_exception(page)

        t0 = time.perf_counter()
        page.get_by_role("tab", name="Learning curves").click()
        charts = page.locator('[data-testid="stVegaLiteChart"]')
        charts.nth(1).wait_for(timeout=30_000)
        page.locator('[data-testid="stVegaLiteChart"] canvas, [data-testid="stVegaLiteChart"] svg').first.wait_for(
            timeout=30_000)
        page.wait_for_timeout(1500)  # let vega finish drawing
        print(f"browser: learning curves rendered in {time.perf_counter() - t0:.2f} s")
        assert charts.count() == 2  # one per env of the fixture
        _no_exception(page)
        page.screenshot(path=str(tmp_path / "curves.png"), full_page=True)
        shutil.copy(tmp_path / "curves.png", "/tmp/dashboard.png")

        page.get_by_role("tab", name="Table 1").click()
        table = page.locator('[data-testid="stMarkdown"] table')
        table.first.wait_for(timeout=30_000)
        text = table.first.inner_text()
        assert "MEDAL" in text and "0.70 (0.06)" in text, text  # tabletop medal: 0.6 + mean offset 0.1
        assert table.first.locator("strong").count() >= 2  # best entries bold
        _no_exception(page)
        page.screenshot(path=str(tmp_path / "table1.png"), full_page=True)
        shutil.copy(tmp_path / "table1.png", "/tmp/dashboard_table1.png")


def test_page_load_time_100_runs_x_300_evals(tmp_path):
    """A fresh server and browser page on 100 runs x 300 evaluations: time until the main page
    (Runs: state counts and the status table) and then the 4 learning-curve charts are drawn.
    Printed; the bound is generous (shared CI machines), the target is < 3 s for the main page."""
    big = write_big(tmp_path / "big", runs=100, evals=300)
    with serve(big, tmp_path / "streamlit.log") as url, chromium() as browser:
        page = browser.new_page(viewport={"width": 1500, "height": 1100})
        t0 = time.perf_counter()
        page.goto(url, wait_until="domcontentloaded")
        page.locator('[data-testid="stDataFrame"]').first.wait_for(timeout=60_000)
        page.locator('[data-testid="stMetric"]').first.wait_for(timeout=60_000)
        main = time.perf_counter() - t0
        t0 = time.perf_counter()
        page.get_by_role("tab", name="Learning curves").click()
        page.locator('[data-testid="stVegaLiteChart"] canvas, [data-testid="stVegaLiteChart"] svg').nth(3).wait_for(
            timeout=60_000)
        curves = time.perf_counter() - t0
        print(f"\nbrowser, 100 runs x 300 evals: main page {main:.2f} s (incl. page/JS load), "
              f"learning curves tab {curves:.2f} s")
        _no_exception(page)
        assert main < 30 and curves < 30
