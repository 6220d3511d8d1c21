"""The Streamlit dashboard (app.py) under ``streamlit.testing.v1.AppTest``, one test per tab, on the
synthetic results of ``tests/fixtures_results.py``; plus the empty-directory how-to and a load-time
check on 100 runs x 300 evaluations."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("streamlit")
from streamlit.testing.v1 import AppTest  # noqa: E402

from harness import analysis as A  # noqa: E402
from harness.labels import method_color  # noqa: E402
from harness.results import load  # noqa: E402
from harness.stats import iqm  # noqa: E402
from tests import fixtures_results as F  # noqa: E402

APP = str(Path(__file__).resolve().parent.parent / "app.py")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return F.write_fixture(tmp_path_factory.mktemp("results"), corrupt=True)


def run_app(monkeypatch, results, tab: str | None = None, **state) -> AppTest:
    monkeypatch.setenv("HARNESS_RESULTS", str(results))
    at = AppTest.from_file(APP, default_timeout=60)
    if tab:
        at.query_params["tab"] = tab
    for k, v in state.items():
        at.session_state[k] = v
    at.run()
    assert not at.exception, [e.value for e in at.exception]
    return at


def texts(at, kind: str) -> list[str]:
    return [str(e.value) for e in at.get(kind)]


def test_runs_tab(monkeypatch, results):
    at = run_app(monkeypatch, results)  # the default tab
    warnings = texts(at, "warning")
    assert any("broken/seed=0/evals.parquet" in w for w in warnings), warnings  # corrupt file named, rest shown
    counts = {m.label: int(m.value) for m in at.metric}
    assert counts == {"running": 1, "resumed": 1, "stale": 1, "done": 15, "failed": 1, "unknown": 1}
    table = at.dataframe[0].value
    assert len(table) == 20 and {"state", "progress", "steps_per_s", "ETA", "last_success", "error"} <= set(table)
    assert table["state"].str.contains("stale").sum() == 1
    assert any(F.FAILED_ERROR in e for e in texts(at, "error"))
    assert "second line" not in " ".join(texts(at, "error"))


def test_learning_curves_tab(monkeypatch, results):
    at = run_app(monkeypatch, results, "Learning curves")
    assert len(at.get("vega_lite_chart")) == 2  # one per env
    c = at.dataframe[0].value  # "curve data" expander
    last = c[(c["env"] == "tabletop_manipulation") & (c["algo"] == "medal") & (c["step"] == F.STEPS)].iloc[0]
    mean, se = F.expected_final("tabletop_manipulation", "medal")
    assert last["mean"] == pytest.approx(mean) and last["se"] == pytest.approx(se)
    # bootstrap CI band, smoothing, the continuing metric, no published overlay
    at.radio(key="band").set_value("95% bootstrap CI")
    at.slider(key="smooth").set_value(3)
    at.selectbox(key="curve_metric").set_value("continuing_reward_rate")
    at.multiselect(key="sources").set_value([])
    at.run()
    assert not at.exception
    c = at.dataframe[0].value
    assert c["ci_lo"].notna().all() and (c["step"] > 0).all()
    assert len(at.get("vega_lite_chart")) == 2
    spec = json.loads(at.get("vega_lite_chart")[0].proto.spec)  # the report's fixed colours (harness.labels)
    assert all(method_color(a) in json.dumps(spec) for a in F.ALGOS)


def test_table1_tab(monkeypatch, results):
    at = run_app(monkeypatch, results, "Table 1")
    md = "\n".join(texts(at, "markdown"))
    mean, se = F.expected_final("tabletop_manipulation", "medal")
    assert f"**{mean:.2f} ({se:.2f})**" in md and "0.98 (0.02)" in md  # ours (best, bold) beside the paper
    assert [b.label for b in at.get("download_button")] == ["CSV", "Markdown", "LaTeX"]
    at.radio(key="t1_how").set_value("step N")
    at.run()
    at.number_input(key="t1_n").set_value(50_000)
    at.run()
    md = "\n".join(texts(at, "markdown"))
    assert f"**{0.7 * 0.5 + 0.1:.2f} (" in md  # sawyer door medal at 50k
    at.toggle(key="t1_pub").set_value(False)
    at.run()
    assert "paper" not in "\n".join(texts(at, "markdown"))


def test_aggregates_tab(monkeypatch, results):
    at = run_app(monkeypatch, results, "Aggregates")
    agg = at.dataframe[0].value.set_index("method")
    d = load(results, warn=lambda m: None)
    scores = A.final_scores(d[~A.is_tuning(d)])  # tuning trials are left out by default
    pooled = scores.loc[scores["algo"] == "medal", "score"].to_numpy()
    assert agg.loc["MEDAL", "iqm"] == pytest.approx(iqm(pooled))
    assert agg.loc["MEDAL", "iqm_lo"] <= agg.loc["MEDAL", "iqm"] <= agg.loc["MEDAL", "iqm_hi"]
    poi = at.metric[0]
    assert poi.label == "P(MEDAL > naive RL)" and poi.value == "1.00"  # every medal run beats every naive run


def test_ablations_tab(monkeypatch, results):
    at = run_app(monkeypatch, results, "Ablations")
    heads = texts(at, "subheader")
    assert heads == ["Reward form (MEDAL vs log C)"]  # only medal + medal_logc have results
    assert len(at.get("vega_lite_chart")) == 2


def test_tuning_tab(monkeypatch, results):
    at = run_app(monkeypatch, results, "Tuning")
    try:
        import optuna  # noqa: F401
    except ImportError:
        assert any("Optuna" in t for t in texts(at, "info"))
        return
    assert texts(at, "subheader") == ["medal_sawyer_door"]
    best = at.dataframe[0].value
    assert {"trial", "value 0", "lr", "batch_size"} <= set(best.columns)


def test_tuning_trials_toggle(monkeypatch, results):
    at = run_app(monkeypatch, results, "Runs", tuning_runs=True)
    assert len(at.dataframe[0].value) == 21  # + the trial run under tuning/
    assert f"tune_{F.TUNE_STUDY}" in at.selectbox(key="suite").options
    at = run_app(monkeypatch, results, "Learning curves", tuning_runs=True, suite=f"tune_{F.TUNE_STUDY}")
    assert len(at.get("vega_lite_chart")) == 1  # the trial ran on sawyer_door only
    at.selectbox(key="suite").set_value("fixture")
    at.run()
    assert not at.exception and len(at.get("vega_lite_chart")) == 2


def test_empty_and_missing_dirs(monkeypatch, tmp_path):
    at = run_app(monkeypatch, tmp_path)
    md = "\n".join(texts(at, "markdown"))
    assert "No results yet" in md and "harness run suite=smoke" in md
    at = run_app(monkeypatch, tmp_path / "nope")
    assert any("does not exist" in w for w in texts(at, "warning"))


def test_pages_on_100_runs_x_300_evals(monkeypatch, tmp_path):
    """Cold caches: 100 runs x 300 evaluations (6 metrics) render on the main page (Runs), Learning curves and
    Table 1 with no exception. Load time is measured by ``harness bench app``, not here."""
    import streamlit as st

    big = F.write_big(tmp_path / "big", runs=100, evals=300)
    st.cache_data.clear()
    st.cache_resource.clear()
    for tab in ("Runs", "Learning curves", "Table 1"):
        at = run_app(monkeypatch, big, tab)
        assert not at.exception, at.exception
    assert "100 runs with results" in " ".join(texts(at, "caption"))
    assert at.markdown  # the Table 1 tab drew its table


def test_diagnostics_tab(monkeypatch, tmp_path):
    """Training diagnostics (train.parquet) per run and metric, smoothed on request."""
    from harness.results import TRAIN_FILE, RunResults, run_dir

    root = F.write_fixture(tmp_path, corrupt=False, tuning=False, failed=False)
    for seed in (0, 1):
        d = run_dir(root, F.SUITE, "tabletop_manipulation", "medal", seed)
        r = RunResults(d, {"suite": F.SUITE, "env": "tabletop_manipulation", "algo": "medal", "seed": seed},
                       {"config_hash": "x", "members": 1}, TRAIN_FILE)
        for step in range(1000, 11_000, 1000):
            r.append(step, {"forward/critic_loss": step / 1000 + seed, "discriminator/accuracy": 0.5}, flush=False)
        r.flush()
    at = run_app(monkeypatch, tmp_path, "Diagnostics")
    assert at.selectbox(key="diag_metric").value == "forward/critic_loss"
    assert len(at.multiselect(key="diag_runs").value) == 2 and len(at.get("vega_lite_chart")) == 1
    at.selectbox(key="diag_metric").set_value("discriminator/accuracy")
    at.slider(key="diag_smooth").set_value(3)
    at.run()
    assert not at.exception and len(at.get("vega_lite_chart")) == 1
    empty = run_app(monkeypatch, F.write_fixture(tmp_path / "none", corrupt=False, tuning=False), "Diagnostics")
    assert any("No training diagnostics" in t for t in texts(empty, "info"))


@pytest.fixture(scope="module")
def mixed(tmp_path_factory):
    return F.write_mixed_suites(tmp_path_factory.mktemp("mixed"))


def test_each_tab_opens_on_its_own_view_and_never_pools_suites(monkeypatch, mixed):
    """Issue 58: after a smoke run beside the shipped tables, Table 1 shows the Table-1 cells from the suites that check
    them (not the 400-step smoke seed, not RISC's non-Table-1 cell), Learning curves the latest suite (smoke), Ablations
    each group from one suite; with suite "all" a method run in two suites is two rows, never one pooled row."""
    at = run_app(monkeypatch, mixed, "Table 1")
    md = "\n".join(texts(at, "markdown"))
    assert "| MEDAL | **1.00 (0.00)** | **0.98 (0.02)** | +0.02 | **0.00 (0.00)** @400k† |" in md, md  # tabletop:
    # the 3 reproduction seeds, not pooled with the smoke seed; peg from table1, far from the paper's 8M: marked
    assert "smoke" not in md and "RISC" not in md and "· " not in md
    assert any("Table-1 cells" in c for c in texts(at, "caption"))

    at = run_app(monkeypatch, mixed, "Learning curves")
    c = at.dataframe[0].value
    assert set(c["algo"]) == {a for (s, _, a) in F.MIXED if s == "smoke"} and c["step"].max() == 400
    assert any("Suite **smoke**, the most recently updated" in t for t in texts(at, "caption"))

    at = run_app(monkeypatch, mixed, "Ablations")
    assert texts(at, "subheader") == ["Imitation (BC / GAIL vs MEDAL)", "State distribution (MEDAL vs FBRL + VICE)",
                                      "Reward form (MEDAL vs log C)"]
    caps = texts(at, "caption")
    assert caps[0].startswith("Suite **imitation**: 2 of the group's 4 methods, evaluations up to step 200,000. "
                              "Other suites with two or more: smoke")  # the larger budget wins over the smoke test
    assert sum("Suite **smoke**" in t for t in caps) == 2
    assert "0.90 (0.00) @200,000" in at.dataframe[0].value.to_string()
    assert "0.00 (1 seed) @400" in at.dataframe[1].value.to_string()

    at = run_app(monkeypatch, mixed, "Aggregates")
    agg = at.dataframe[0].value.set_index("method")
    assert list(agg.index) == ["MEDAL"] and agg.loc["MEDAL", "n_runs"] == 5  # 3 tabletop + 2 peg seeds
    assert any(c.startswith("Scores from step MEDAL: Tabletop Organization 1.5M, Sawyer Peg 400k†; † before half")
               for c in texts(at, "caption")), texts(at, "caption")  # each number's step, early ones marked

    at = run_app(monkeypatch, mixed, "Table 1", suite="all")
    md = next(t for t in texts(at, "markdown") if "ours | " in t)  # Table 1 (the evidence grid follows)
    assert "| MEDAL · reproduction | **1.00 (0.00)** @1.5M |" in md and "| MEDAL · smoke | 0.00 (1 seed) @400† |" in md
    assert "| MEDAL |" not in md
    at = run_app(monkeypatch, mixed, "Ablations", suite="all")
    assert "Imitation (BC / GAIL vs MEDAL) · imitation" in texts(at, "subheader")


def test_curves_of_return_envs_open_on_the_return_with_earls_curves(monkeypatch, tmp_path):
    """Runs on kitchen only: the curves tab opens on the deployed return (what the published curves measure there)
    with EARL's own curves overlaid (kitchen's are source earl_benchmark); a Sawyer selection keeps success."""
    from harness.synthetic import write_run

    status = {"state": "done", "step": 100_000, "total": 100_000, "steps_per_s": 20.0, "eta_s": 0.0, "last_success": 0}
    for s in (0, 1):
        write_run(tmp_path, "mine", "kitchen", "naive", s, range(0, 100_001, 10_000),
                  lambda step: {"deployed_success": 0.0, "deployed_return": -2700.0 + step / 1000,
                                "steps_per_s": 20.0, "wall_s": step / 20}, status)
    at = run_app(monkeypatch, tmp_path, "Learning curves")
    assert at.selectbox(key="curve_metric").value == "deployed_return"
    assert at.multiselect(key="sources").value == ["risc_paper", "earl_benchmark"]
    c = at.dataframe[0].value
    assert c["mean"].min() == pytest.approx(-2700.0) and len(at.get("vega_lite_chart")) == 1


def test_curves_of_sawyer_envs_open_on_success(monkeypatch, results):
    at = run_app(monkeypatch, results, "Learning curves")
    assert at.selectbox(key="curve_metric").value == "deployed_success"
    assert at.multiselect(key="sources").value == ["risc_paper"]


def test_bench_app_waits_for_the_charts_of_the_default_suite(tmp_path):
    """`harness bench app results=DIR` waits for as many learning-curve charts as the tab draws by default: one per
    env of the most recently updated suite, not of every suite (the real results/ has several)."""
    import os

    from harness.bench.app import chart_count

    for n, (suite, env) in enumerate([("old", "tabletop_manipulation"), ("old", "sawyer_door"), ("old", "sawyer_peg"),
                                      ("new", "sawyer_peg")]):
        d = tmp_path / suite / env / "medal" / "seed=0"
        d.mkdir(parents=True)
        (d / "evals.parquet").write_bytes(b"")
        (d / "status.json").write_text("{}")
        os.utime(d / "status.json", (1_000_000 + n, 1_000_000 + n))
    assert chart_count(tmp_path) == 1
    os.utime(tmp_path / "old" / "sawyer_door" / "medal" / "seed=0" / "status.json", (2_000_000, 2_000_000))
    assert chart_count(tmp_path) == 3 and chart_count(tmp_path / "none") == 0
