"""``harness bench app [runs=100] [evals=300] [repeats=3] [results=DIR]``: dashboard page-load time.

Writes a synthetic results set (``runs`` runs x ``evals`` evaluations, :func:`harness.synthetic.write_big`)
into a temporary directory, or uses ``results=DIR``; starts one ``streamlit run app.py`` server on it
and opens headless-Chromium pages: one cold visit (the first after the server started, empty browser
cache), then ``repeats - 1`` pairs of a new user (server data cache warm, empty browser cache) and a
reload (browser cache holding Streamlit's static files). Per visit: the main page (until the Runs
tab's first state count and status table are visible, page and JS load included) and the Learning
curves tab (from the click until every env's chart is drawn). Target: main page < 3 s.

Needs the ``playwright`` Python package and Debian's ``chromium`` (``apt-get install chromium``;
``/usr/bin/chromium`` or ``HARNESS_CHROMIUM``); ``playwright install`` is not used. The helpers
:func:`serve` and :func:`chromium` are shared with ``tests/test_browser.py``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
APP = ROOT / "app.py"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]
VIEWPORT = {"width": 1500, "height": 1100}
TARGET_MAIN_S = 3.0

METRIC = '[data-testid="stMetric"]'  # Runs tab: state counts
DATAFRAME = '[data-testid="stDataFrame"]'  # Runs tab: status table
CHART_DRAWN = '[data-testid="stVegaLiteChart"] canvas, [data-testid="stVegaLiteChart"] svg'


def chromium_path() -> str | None:
    """``HARNESS_CHROMIUM`` (default /usr/bin/chromium) if it exists, else ``chromium`` on PATH."""
    path = os.environ.get("HARNESS_CHROMIUM", "/usr/bin/chromium")
    return path if Path(path).exists() else shutil.which("chromium")


def missing() -> str | None:
    """Why the browser checks cannot run (playwright or chromium absent), or None."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "playwright (pip install playwright) is not installed"
    if chromium_path() is None:
        return (f"chromium not found at {os.environ.get('HARNESS_CHROMIUM', '/usr/bin/chromium')} "
                "(apt-get install chromium, or set HARNESS_CHROMIUM)")
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(results: Path, log_path: Path, app: Path = APP, start_timeout_s: float = 60):
    """``streamlit run app.py`` on ``results`` at a free 127.0.0.1 port; yields the URL once
    ``/_stcore/health`` answers. Raises RuntimeError (with the server log's tail) if it does not start."""
    port = free_port()
    env = {**os.environ, "HARNESS_RESULTS": str(results)}
    url = f"http://127.0.0.1:{port}"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "streamlit", "run", str(app), "--server.headless", "true",
             "--server.port", str(port), "--server.address", "127.0.0.1", "--browser.gatherUsageStats", "false",
             "--server.fileWatcherType", "none", "--", "--results", str(results)],
            cwd=Path(app).parent, env=env, stdout=log, stderr=subprocess.STDOUT,
        )
        try:
            deadline = time.time() + start_timeout_s
            while True:
                try:
                    if urllib.request.urlopen(url + "/_stcore/health", timeout=2).status == 200:
                        break
                except OSError:
                    pass
                if proc.poll() is not None or time.time() > deadline:
                    log.flush()
                    raise RuntimeError(f"streamlit did not start ({log_path}): "
                                       + Path(log_path).read_text()[-2000:])
                time.sleep(0.2)
            yield url
        finally:
            proc.terminate()
            try:
                proc.wait(10)
            except subprocess.TimeoutExpired:
                proc.kill()


@contextlib.contextmanager
def chromium():
    """Headless Chromium (Debian's, see :func:`chromium_path`) through Playwright; yields the browser."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium_path(), args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


def chart_count(results: Path) -> int:
    """Charts the Learning curves tab draws by default: one per env of its default suite, the most recently updated
    (the newest ``status.json``; tuning trials left out)."""
    runs = [p.parent for p in Path(results).glob("*/*/*/seed=*/evals.parquet")
            if p.relative_to(results).parts[0] != "tuning"]
    if not runs:
        return 0
    age = {d: (d / "status.json").stat().st_mtime if (d / "status.json").exists() else 0.0 for d in runs}
    suite = max(runs, key=age.get).relative_to(results).parts[0]
    return len({d.relative_to(results).parts[1] for d in runs if d.relative_to(results).parts[0] == suite})


def time_visit(context, url: str, charts: int, timeout_s: float = 120) -> tuple[float, float | None]:
    """One new page in a browser ``context``: (main page s, learning curves s); curves is None when there are no
    charts. A context is a browser profile: a new one has an empty cache, a used one has Streamlit's static files."""
    ms = timeout_s * 1000
    page = context.new_page()
    try:
        t0 = time.perf_counter()
        page.goto(url, wait_until="domcontentloaded", timeout=ms)
        page.locator(METRIC).first.wait_for(timeout=ms)
        page.locator(DATAFRAME).first.wait_for(timeout=ms)
        main = time.perf_counter() - t0
        curves = None
        if charts:
            t0 = time.perf_counter()
            page.get_by_role("tab", name="Learning curves").click(timeout=ms)
            page.locator(CHART_DRAWN).nth(charts - 1).wait_for(timeout=ms)
            curves = time.perf_counter() - t0
        if page.locator('[data-testid="stException"]').count():
            raise RuntimeError("the dashboard shows an exception: " + page.inner_text("body")[:1000])
        return main, curves
    finally:
        page.close()


def _s(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def bench_app(runs: int = 100, evals: int = 300, repeats: int = 3, results: str | Path | None = None,
              timeout_s: float = 120, log=print) -> dict:
    """Time page visits against one server: a cold one, then ``repeats - 1`` pairs of (new user, reload); prints a
    table. Returns ``{"rows": [{visit, kind, main_s, curves_s}], "summary": {kind: medians}}``."""
    from harness.synthetic import write_big

    with tempfile.TemporaryDirectory(prefix="harness_bench_app_") as tmp:
        if results is None:
            t0 = time.perf_counter()
            root = write_big(Path(tmp) / "results", runs=runs, evals=evals)
            what = f"synthetic {runs} runs x {evals} evals (written in {time.perf_counter() - t0:.1f} s)"
        else:
            root, what = Path(results), f"results={results}"
        charts = chart_count(root)
        t0 = time.perf_counter()
        with serve(root, Path(tmp) / "streamlit.log") as url, chromium() as browser:
            log(f"bench app: {what}; server up in {time.perf_counter() - t0:.1f} s; 1 cold visit, then "
                f"{repeats - 1} x (new user, reload); {charts} learning-curve chart(s)")
            log("  cold: first visit after the server started, empty browser cache")
            log("  new user: server data cache warm, empty browser cache (a colleague opening the link)")
            log("  reload: server data cache warm, browser cache holding Streamlit's static files")
            log(f"{'visit':>5}  {'':<8}  {'main page s':>11}  {'learning curves s':>17}")
            home = browser.new_context(viewport=VIEWPORT)
            rows = []
            kinds = ["cold"] + ["new user", "reload"] * (repeats - 1)
            for i, kind in enumerate(kinds, 1):
                context = home if kind != "new user" else browser.new_context(viewport=VIEWPORT)
                main, curves = time_visit(context, url, charts, timeout_s)
                if context is not home:
                    context.close()
                rows.append({"visit": i, "kind": kind, "main_s": main, "curves_s": curves})
                log(f"{i:>5}  {kind:<8}  {main:>11.2f}  {_s(curves):>17}")
    summary = {}
    for kind in ("cold", "new user", "reload"):
        sel = [r for r in rows if r["kind"] == kind]
        if sel:
            summary[kind] = {"main_s": statistics.median(r["main_s"] for r in sel),
                             "curves_s": None if charts == 0 else statistics.median(r["curves_s"] for r in sel)}
    log(f"main page (median; target < {TARGET_MAIN_S:g} s): "
        + ", ".join(f"{k} {v['main_s']:.2f} s" for k, v in summary.items())
        + "; learning curves: " + ", ".join(f"{k} {_s(v['curves_s'])} s" for k, v in summary.items()))
    return {"rows": rows, "summary": summary}


def bench_app_cli(ov: dict[str, str]) -> int:
    from harness.words import UsageError, optional_integer

    runs, evals = optional_integer("runs", ov.get("runs"), 100, 1), optional_integer("evals", ov.get("evals"), 300, 1)
    repeats = optional_integer("repeats", ov.get("repeats"), 3, 1)
    results = ov.get("results")
    if results is not None and not Path(results).is_dir():
        raise UsageError(f"results directory {results!r} does not exist")
    if not APP.exists():
        raise UsageError(f"{APP} not found: run bench app from a source checkout")
    why = missing()
    if why:
        raise UsageError(f"bench app needs a browser: {why}")
    from playwright.sync_api import Error as PlaywrightError

    try:
        bench_app(runs, evals, repeats, results)
    except (RuntimeError, PlaywrightError) as e:  # server did not start, a page timed out or crashed
        print("harness: error: bench app: " + " ".join(str(e).split())[:2000], file=sys.stderr)
        return 1
    return 0
