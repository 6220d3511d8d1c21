"""End-to-end: the dashboard served by ``streamlit run`` and opened in headless Chromium (Playwright).

Needs the ``playwright`` Python package and Debian's ``chromium`` (``apt-get install chromium``:
/usr/bin/chromium, or ``HARNESS_CHROMIUM``); ``playwright install`` is not used. Skipped with the
reason when either is missing. The helpers (``serve``, ``chromium``) live in ``harness.bench.app``;
page-load time is measured by ``harness bench app``, not here. Saves screenshots to the test's tmp
dir and once to /tmp/dashboard.png (learning curves) and /tmp/dashboard_table1.png.
"""

from __future__ import annotations

import shutil
import time

import pytest

from harness.bench.app import VIEWPORT, bench_app, chromium, missing, serve
from tests.fixtures_results import write_fixture

pytestmark = pytest.mark.skipif(missing() is not None, reason=missing() or "")


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
        page = browser.new_page(viewport=VIEWPORT)
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


def test_bench_app_tiny(capsys):
    """``harness bench app`` end to end at a tiny size: a row per visit with positive times. Timing is
    measured by the benchmark itself (default size: 100 runs x 300 evals), never asserted here."""
    out = bench_app(runs=4, evals=20, repeats=2)
    printed = capsys.readouterr().out
    rows = out["rows"]
    assert [(r["visit"], r["kind"]) for r in rows] == [(1, "cold"), (2, "new user"), (3, "reload")]
    assert all(r["main_s"] > 0 and r["curves_s"] > 0 for r in rows), rows
    assert {k: v["main_s"] for k, v in out["summary"].items()} == {r["kind"]: r["main_s"] for r in rows}
    lines = printed.splitlines()
    assert any(line.split()[:2] == ["1", "cold"] for line in lines), printed
    assert any(line.split()[:3] == ["3", "reload", f"{rows[2]['main_s']:.2f}"] for line in lines), printed
    assert "target < 3 s" in printed, printed


def test_reproduction_and_diagnostics_tabs_in_chromium(tmp_path):
    """The Reproduction tab (a panel per cell, the verdict table) and the Diagnostics tab (a chart of train.parquet)
    served by ``streamlit run`` and drawn in Chromium."""
    from harness.results import TRAIN_FILE, RunResults, run_dir
    from tests.test_reproduction import write_ladder_results

    root = write_ladder_results(tmp_path / "results")
    for seed in (0, 1):
        ident = {"suite": "reproduction", "env": "tabletop_manipulation", "algo": "risc", "seed": seed}
        r = RunResults(run_dir(root, *ident.values()), ident, {"config_hash": "x", "members": 2}, TRAIN_FILE)
        for step in range(1000, 11_000, 1000):
            r.append(step, {"sac/critic_loss": step / 1000 + seed}, flush=False)
        r.flush()
    with serve(root, tmp_path / "streamlit.log") as url, chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(url, wait_until="domcontentloaded")
        page.locator('[data-testid="stMetric"]').first.wait_for(timeout=30_000)
        page.get_by_role("tab", name="Reproduction").click()
        charts = page.locator('[data-testid="stVegaLiteChart"]')
        charts.nth(8).wait_for(timeout=60_000)  # one panel per cell of suites/reproduction.yaml
        page.locator('[data-testid="stDataFrame"]').first.wait_for(timeout=30_000)  # the verdict table (a canvas grid)
        assert charts.count() == 9 and page.get_by_text("fail (too weak)").count() >= 1
        _no_exception(page)
        page.screenshot(path=str(tmp_path / "reproduction.png"), full_page=True)

        page.get_by_role("tab", name="Diagnostics").click()
        page.get_by_text("sac/critic_loss").first.wait_for(timeout=30_000)
        page.locator('[data-testid="stVegaLiteChart"] canvas, [data-testid="stVegaLiteChart"] svg').last.wait_for(
            timeout=30_000)
        _no_exception(page)


def test_default_views_never_pool_suites_in_chromium(tmp_path):
    """Issue 58: a smoke run beside the shipped tables (tests/fixtures_results.py:MIXED), served and drawn in Chromium:
    Table 1 shows the Table-1 cells (MEDAL 1.00 from its 3 reproduction seeds, peg at @400k†), Learning curves the smoke
    suite alone, Ablations one suite per group (the largest budget); no method's name carries a suite (nothing split, nothing pooled).
    Screenshots: /tmp/dashboard_default_{table1,curves,ablations}.png."""
    from tests.fixtures_results import write_mixed_suites

    with serve(write_mixed_suites(tmp_path / "results"), tmp_path / "streamlit.log") as url, chromium() as browser:
        page = browser.new_page(viewport=VIEWPORT)
        page.goto(url, wait_until="domcontentloaded")
        page.locator('[data-testid="stMetric"]').first.wait_for(timeout=30_000)

        page.get_by_role("tab", name="Table 1").click()
        table = page.locator('[data-testid="stMarkdown"] table')
        table.first.wait_for(timeout=30_000)
        text = table.first.inner_text()
        assert "1.00 (0.00)" in text and "@400k†" in text and "smoke" not in text and "RISC" not in text, text
        page.get_by_text("The Table-1 cells, each from the runs").wait_for(timeout=30_000)
        _no_exception(page)
        page.screenshot(path="/tmp/dashboard_default_table1.png", full_page=True)

        page.get_by_role("tab", name="Learning curves").click()
        page.get_by_text("Suite smoke, the most recently updated").wait_for(timeout=30_000)
        page.locator('[data-testid="stVegaLiteChart"] canvas, [data-testid="stVegaLiteChart"] svg').first.wait_for(
            timeout=30_000)
        page.wait_for_timeout(1500)
        assert page.locator('[data-testid="stVegaLiteChart"]').count() == 1  # tabletop only: smoke's env
        _no_exception(page)
        page.screenshot(path="/tmp/dashboard_default_curves.png", full_page=True)

        page.get_by_role("tab", name="Ablations").click()
        page.get_by_text("Reward form (MEDAL vs log C)").wait_for(timeout=30_000)
        page.wait_for_timeout(1500)
        main = page.locator('[data-testid="stMain"]').inner_text()
        assert page.get_by_text("Suite smoke:").count() == 2 and page.get_by_text("Suite imitation:").count() == 1 and "· smoke" not in main and "· imitation" not in main
        _no_exception(page)
        page.screenshot(path="/tmp/dashboard_default_ablations.png", full_page=True)
