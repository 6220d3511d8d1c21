"""The reproduction ladder (suites/reproduction.yaml, harness/reproduction.py, docs/reproduction.md): the suite's
published numbers agree with the data, the criterion passes / fails / waits as documented, a suite of cells plans
its runs (and variants) exactly, and the report and the dashboard tab show verdicts."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from harness import ladder_provenance as P
from harness import reproduction as R
from harness.planning import plan_words
from harness.results import run_dir
from harness.suites import ConfigError
from harness.synthetic import write_run

from .conftest import requires_data

SUITES = ("reproduction", "vaprl_ablation", "table1", "earl_returns", "peg_oracle_diagnosis", "naive_tabletop_diagnosis")


def _curves(values: dict[int, list[float]], start: int = 10_000, every: int = 10_000) -> pd.DataFrame:
    rows = [{"seed": s, "step": start + i * every, "value": v} for s, vals in values.items() for i, v in enumerate(vals)]
    return pd.DataFrame(rows)


CELL = R.Cell("x", "x", "tabletop_manipulation", 100_000, (0, 1), (R.Check(50_000, 100_000, "src", "x", 0.6, 0.4, 0.8),))


def test_criterion_passes_faithful_fails_weak_and_too_strong_waits_for_the_window():
    check = CELL.checks[0]
    ten = lambda a, b: [0.0] * 5 + list(np.linspace(a, b, 5))  # noqa: E731 - evals 10k..100k, window = last 5
    # a seed that collapses (0.2) beside one at the top (0.9): mean 0.55 is inside [0.3, 0.9]
    v = R.verdict(_curves({0: ten(0.2, 0.2), 1: ten(0.9, 0.9)}), CELL, check, 0.1)
    assert v["status"] == "pass" and v["ours"] == pytest.approx(0.55) and v["ours_per_seed"] == pytest.approx([0.2, 0.9])
    assert v["lower"] == pytest.approx(0.3) and v["upper"] == pytest.approx(0.9)
    weak = R.verdict(_curves({0: ten(0.1, 0.1), 1: ten(0.2, 0.2)}), CELL, check, 0.1)
    assert weak["status"] == "fail" and R.verdict_text(weak, check, CELL.steps) == "fail (too weak)"
    strong = R.verdict(_curves({0: ten(1.0, 1.0), 1: ten(0.95, 0.95)}), CELL, check, 0.1)
    assert strong["status"] == "fail" and R.verdict_text(strong, check, CELL.steps) == "fail (too strong)"
    # one seed short of the window's last evaluation: running, whatever the values; here no last evaluation
    # (0 or 1) can move the seed-mean out of [0.3, 0.9], so the text says the pass is decided
    partial = _curves({0: ten(0.6, 0.6), 1: ten(0.6, 0.6)[:-1]})
    v = R.verdict(partial, CELL, check, 0.1)
    assert v["status"] == "running" and v["reached"] == 90_000 and v["decided"] == "pass"
    assert v["bounds"] == pytest.approx((0.54, 0.64))  # seed 1 ends at 2.4 / 5 or 3.4 / 5
    assert R.verdict_text(v, check, CELL.steps) == ("running: 2 seeds, the slowest at 90,000, the furthest at "
                                                    "100,000 of 100,000 steps; pass whatever the rest scores")
    level = R.verdict(_curves({0: ten(0.6, 0.6)[:-1], 1: ten(0.6, 0.6)[:-1]}), CELL, check, 0.1)
    assert R.verdict_text(level, check, CELL.steps) == "running: reached 90,000 of 100,000 steps; pass whatever the rest scores"
    assert R.verdict_text(level, check, CELL.steps, short=True) == "at 90,000 of 100,000 steps, pass already"
    # 0.0 at three of five window evaluations: bounds (0.0, 0.4) straddle the band's lower edge 0.3, undecided;
    # 0.0 at four of five: at most 0.2, a fail already
    open_ = R.verdict(_curves({0: ten(0.0, 0.0)[:-2], 1: ten(0.0, 0.0)[:-2]}), CELL, check, 0.1)
    assert open_["decided"] is None and open_["bounds"] == pytest.approx((0.0, 0.4))
    assert R.verdict_text(open_, check, CELL.steps) == "running: reached 80,000 of 100,000 steps"
    weak_soon = R.verdict(_curves({0: ten(0.0, 0.0)[:-1], 1: ten(0.0, 0.0)[:-1]}), CELL, check, 0.1)
    assert weak_soon["decided"] == "fail" and R.verdict_text(weak_soon, check, CELL.steps, short=True) == (
        "at 90,000 of 100,000 steps, fail (too weak) already")
    low = R.Check(50_000, 100_000, "src", "x", 0.4, 0.3, 0.5)  # band [0.2, 0.6]; 1.0 at four of five: at least 0.8
    strong_soon = R.verdict(_curves({0: ten(1.0, 1.0)[:-1], 1: ten(1.0, 1.0)[:-1]}), CELL, low, 0.1)
    assert strong_soon["decided"] == "fail" and R.verdict_text(strong_soon, low, CELL.steps) == (
        "running: reached 90,000 of 100,000 steps; fail (too strong) whatever the rest scores")
    assert R.verdict_text(R.verdict(partial.iloc[:0], CELL, check, 0.1), check, CELL.steps) == "not started"
    one = R.verdict(partial[partial["seed"] == 1], CELL, check, 0.1)  # seed 0 not begun
    assert one["status"] == "running" and one["reached"] == 0 and one["started"] == 1
    assert R.verdict_text(one, check, CELL.steps) == ("running: 1 of 2 seeds started, the furthest at 90,000 of "
                                                      "100,000 steps")
    assert R.verdict_text(one, check, CELL.steps, short=True) == "1 of 2 seeds at 90,000 of 100,000 steps"
    assert R.verdict_text(v, check, CELL.steps, short=True) == "2 seeds at 90,000-100,000 of 100,000 steps, pass already"
    # evaluations outside (lo, hi] do not count
    assert R.window_means(_curves({0: [1.0] * 10}, start=0), 50_000, 100_000).tolist() == [1.0]


def test_seed_mean_stops_where_the_slowest_seed_stops():
    # seed 0 to 100k at 1.0, seed 1 to 30k at 0.0: the mean is 0.5 to 30k and absent beyond (not seed 0 alone)
    m = R.seed_mean(_curves({0: [1.0] * 10, 1: [0.0] * 3}))
    assert m.index.tolist() == [10_000, 20_000, 30_000] and m.tolist() == [0.5, 0.5, 0.5]
    assert R.seed_mean(_curves({0: [1.0] * 3}).iloc[:0]).empty


@requires_data
@pytest.mark.parametrize("suite", SUITES)
def test_suite_published_numbers_match_the_published_curves(suite):
    """Every check's published mean / min / max (2 decimals for a success rate, 1 for a return) are the per-seed window
    means of the data, in the env's metric."""
    from harness.results import load_published

    pub = load_published()
    ladder = R.load_ladder(suite)
    assert ladder.widen == 0.1
    n = 0
    for cell in ladder.cells:
        for check in cell.checks:
            p = R.published_curves(pub, check, cell.env)
            per_seed = R.window_means(p, check.lo, check.hi)
            # 5 published seeds, but 4 for MEDAL peg's 6.5M-6.6M (one published seed has no evaluations there)
            assert len(per_seed) == (4 if (cell.algo, cell.env, check.lo) == ("medal", "sawyer_peg", 6_500_000) else 5)
            assert (check.mean, check.min, check.max) == pytest.approx(
                (per_seed.mean(), per_seed.min(), per_seed.max()), abs=0.0051 if cell.bounded else 0.051), (cell, check)
            n += 1
    # checks: the ladder has 9 cells (vaprl tabletop: two windows), the ablation 22 cells (two of them: two windows),
    # the peg diagnosis 3 cells of two windows
    assert n == {"reproduction": 10, "vaprl_ablation": 24, "table1": 12, "earl_returns": 3, "peg_oracle_diagnosis": 6,
                 "naive_tabletop_diagnosis": 2}[suite]


@requires_data
def test_cells_plan_their_own_budgets_seeds_members_and_variants(tmp_path):
    plan = plan_words(["suite=reproduction", f"results={tmp_path}"])
    got = [(g.env, g.algo, g.steps, tuple(g.seeds)) for g in plan.groups]
    # a cell's seeds as members of one process; one seed per process for forward-backward methods (harness.packing)
    assert got[:3] == [("tabletop_manipulation", "medal", 1_500_000, (s,)) for s in (0, 1, 2)]
    assert ("sawyer_peg", "oracle", 1_000_000, (0, 1)) in got and len(got) == 13
    assert sum(g.steps * len(g.seeds) for g in plan.groups) == 17_700_000
    # selecting cells; a cell's hash is the ad-hoc run's (same env, algo, config, protocol)
    one = plan_words(["suite=reproduction", "algo=risc", "env=sawyer_door", f"results={tmp_path}"]).groups
    adhoc = plan_words(["algo=risc", "env=sawyer_door", "seeds=2", f"results={tmp_path}"]).groups
    assert [(g.algo, g.steps) for g in one] == [("risc", 500_000)]
    assert one[0].config_hash == adhoc[0].config_hash
    # algo= names a cell, or else an algorithm: the ablation's base cell alone, or every variant built on vaprl
    base = plan_words(["suite=vaprl_ablation", "algo=vaprl_risc", f"results={tmp_path}"]).groups
    assert [g.algo for g in base] == ["vaprl_risc"]
    on_vaprl = {g.algo for g in plan_words(["suite=vaprl_ablation", "algo=vaprl", f"results={tmp_path}"]).groups}
    assert "vaprl_goal_terminal" in on_vaprl and not any(a.startswith("vaprl_risc") for a in on_vaprl)
    both = plan_words(["suite=vaprl_ablation", "algo=vaprl_risc_mlp,vaprl", f"results={tmp_path}"]).groups
    assert {g.algo for g in both} == on_vaprl | {"vaprl_risc_mlp"}
    # variants: a name, the base algorithm's class and config overrides; a command-line override still wins
    ab = plan_words(["suite=vaprl_ablation", "vaprl_risc.kappa=0.3", f"results={tmp_path}"]).groups
    by = {g.algo: g for g in ab}
    assert by["vaprl_replay_candidates"].algo_class == "vaprl"
    assert by["vaprl_replay_candidates"].config["candidates"] == "replay"
    assert by["vaprl_demo_relabel"].config["relabel_demos"] is True
    assert by["vaprl_future_demo_relabel"].config["relabel"] == "future_demo"
    assert by["vaprl_goal_terminal"].config["success_ends_phase"] is True
    assert by["vaprl_replay_candidates"].config["relabel_demos"] is False
    fast = by["vaprl_demo_relabel_fast_lambda"].config
    assert fast["relabel_demos"] is True and fast["lagrange_lr"] == 0.003
    assert by["vaprl_demo_relabel"].config["lagrange_lr"] == 3e-4
    assert by["vaprl_risc_no_tab"].algo_class == "vaprl_risc"
    assert by["vaprl_risc_no_tab"].config["bootstrap_on_truncation"] is False
    assert by["vaprl_risc"].config["bootstrap_on_truncation"] is True
    assert {g.config["kappa"] for g in ab if g.algo_class == "vaprl_risc"} == {0.3}  # the override's scope
    assert {g.config["kappa"] for g in ab if g.algo_class == "vaprl" and g.algo != "vaprl_threshold_1000"} == {0.5}
    assert (by["vaprl_threshold_1000"].config["kappa"], by["vaprl_threshold_1000"].config["v_max"]) == (1.0, 1000.0)
    assert by["vaprl_fixed_phases"].config["success_ends_phase"] is False
    assert len({g.config_hash for g in ab}) == len(ab)


@requires_data
@pytest.mark.parametrize("cells, error", [
    ("[{algo: medal, env: tabletop_manipulation}]", "at least algo, env and steps"),
    ("[{algo: medal, env: tabletop_manipulation, steps: 10, colour: red}]", "unknown key(s) ['colour']"),
    ("[{algo: nope, env: tabletop_manipulation, steps: 10}]", "unknown algorithm(s) ['nope']"),
    ("[{algo: medal, env: tabletop_manipulation, steps: 10}, {algo: medal, env: tabletop_manipulation, steps: 20}]",
     "two cells run 'medal' on 'tabletop_manipulation'"),
    ("[{algo: medal, name: 'a b', env: tabletop_manipulation, steps: 10}]", "must be letters, digits"),
    ("[{algo: medal, env: tabletop_manipulation, steps: 10, config: {nope: 1}}]", "unknown config key(s) ['nope']"),
    ("[]", "non-empty list"),
])
def test_bad_cells_are_one_line_errors(tmp_path, cells, error):
    p = tmp_path / "bad.yaml"
    p.write_text(f"cells: {cells}\n")
    with pytest.raises(ConfigError) as e:
        plan_words([f"suite={p}", f"results={tmp_path / 'r'}"])
    assert error in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "r").exists()


def test_cells_and_algos_do_not_mix(tmp_path):
    p = tmp_path / "mixed.yaml"
    p.write_text("algos: [medal]\ncells: [{algo: medal, env: sawyer_door, steps: 10}]\n")
    with pytest.raises(ConfigError, match="belong in its cells"):
        R.load_ladder(str(p))


def write_ladder_results(root: Path) -> Path:
    """Shipped-style results for three reproduction cells: RISC/tabletop at the top (pass), oracle/door at 0 (fail),
    MEDAL/tabletop started (running)."""
    status = {"state": "done", "step": 300_000, "total": 300_000, "steps_per_s": 20.0, "eta_s": 0.0, "last_success": 1}
    for env, algo, steps, seeds, value in (("tabletop_manipulation", "risc", 300_000, (0, 1), 1.0),
                                           ("sawyer_door", "oracle", 300_000, (0, 1), 0.0),
                                           ("tabletop_manipulation", "medal", 50_000, (0, 1, 2), 0.0)):
        for s in seeds:
            write_run(root, "reproduction", env, algo, s, range(0, steps + 1, 10_000),
                      lambda step, v=value: {"deployed_success": v if step else 0.0, "steps_per_s": 20.0,
                                             "wall_s": step / 20}, status)
    return root


def test_ladder_table_and_report(tmp_path, capsys):
    from harness.report import report_cli

    root = write_ladder_results(tmp_path / "results")
    from harness.results import load

    # RISC/tabletop seed 1 resumed at 160k under another commit, from a tree with uncommitted changes, and went back
    # to the first commit at 260k
    f = run_dir(root, "reproduction", "tabletop_manipulation", "risc", 1) / "evals.parquet"
    e = pd.read_parquet(f)
    e.loc[e["step"].between(160_000, 250_000), "git_sha"] = "abcdef0123456789-dirty"
    e.sample(frac=1, random_state=0).to_parquet(f)  # row order must not matter
    t = R.ladder_table(R.load_ladder("reproduction"), load(root)).set_index(["method", "env", "window"])
    assert t.loc[("risc", "tabletop_manipulation", "200k-300k"), "status"] == "pass"
    assert t.loc[("oracle", "sawyer_door", "200k-300k"), "verdict"] == "fail (too weak)"
    assert t.loc[("medal", "tabletop_manipulation", "1400k-1500k"), "verdict"] == "running: reached 50,000 of 1,500,000 steps"
    assert t.loc[("fbrl", "tabletop_manipulation", "1400k-1500k"), "verdict"] == "not started"
    out = tmp_path / "report"
    try:
        assert report_cli(["suite=reproduction", f"results={root}", f"out={out}", "published=none"]) == 0
    except ConfigError as e:  # no published data on this machine: the table still needs none
        pytest.skip(str(e))
    md = (out / "reproduction.md").read_text()
    assert "| risc | tabletop_manipulation | 0.3M | 200k-300k | 0.99 (0.96-1.00) | 1.00 (1.00, 1.00) | pass |" in md
    # the cost: each seed's last wall_s over its process's members (3 in the fixture), env steps summed over seeds
    assert "| risc | tabletop_manipulation | 2 of 2 | 600,000 | 2.8 | 20 |" in md  # 2 x 15,000 s / 3
    assert "| fbrl | tabletop_manipulation | 0 of 2 | 0 | 0.0 | - |" in md
    cost = P.ladder_cost(R.load_ladder("reproduction"), load(root)).set_index(["method", "env"])
    assert cost.loc[("medal", "tabletop_manipulation"), "process_hours"] == pytest.approx(3 * 2_500 / 3 / 3600)
    assert "| total | | 7 of 19 | 1,350,000 |" in md
    # the commits that produced each seed's rows, with the steps each evaluated
    assert "| risc | tabletop_manipulation | 0 | `0000000` (0-300k) |" in md
    assert "| risc | tabletop_manipulation | 1 | `0000000` (0-150k), `abcdef0-dirty` (160k-250k), `0000000` (260k-300k) |" in md
    assert "| medal | tabletop_manipulation | 2 | `0000000` (0-50k) |" in md
    commits = P.ladder_commits(R.load_ladder("reproduction"), load(root))
    assert len(commits) == 7 and sorted(commits["commits"].map(len)) == [1, 1, 1, 1, 1, 1, 3]
    assert P.commits_text([("f" * 40, 50_000, 50_000)]) == "fffffff (50k)"
    assert (out / "reproduction.png").stat().st_size > 10_000
    csv = pd.read_csv(out / "reproduction.csv")
    assert list(csv["status"]).count("pass") == 1 and list(csv["status"]).count("fail") == 1


def test_reproduction_tab(monkeypatch, tmp_path):
    pytest.importorskip("streamlit")
    from tests.test_app import run_app

    root = write_ladder_results(tmp_path / "results")
    at = run_app(monkeypatch, root, "Reproduction")
    counts = {m.label: int(m.value) for m in at.metric}
    assert counts == {"final-window checks": 10, "pass": 1, "fail": 1, "running": 8}
    table = at.dataframe[0].value
    assert len(table) == 10 and set(table["verdict"]) >= {"pass", "fail (too weak)", "not started"}
    assert len(at.get("vega_lite_chart")) == 9  # one panel per cell
    cost = at.dataframe[1].value  # what the runs cost, one row per cell
    assert len(cost) == 9 and cost["started"].sum() == 7 and cost["process_hours"].sum() > 0
    commits = at.dataframe[2].value  # which commits produced the rows, one row per started seed
    assert len(commits) == 7 and set(commits["commits"]) == {"0000000 (0-300k)", "0000000 (0-50k)"}
    at.selectbox(key="repro_suite").set_value("vaprl_ablation")
    at.run()
    assert not at.exception and len(at.get("vega_lite_chart")) == 22  # the ablation: 22 cells
    assert set(at.dataframe[0].value["verdict"]) == {"not started"}


def _write_kitchen_naive(root: Path, value: float = -2700.0) -> Path:
    status = {"state": "done", "step": 1_000_000, "total": 1_000_000, "steps_per_s": 20.0, "eta_s": 0.0,
              "last_success": 0}
    for s in (0, 1):
        write_run(root, "earl_returns", "kitchen", "naive", s, range(0, 1_000_001, 10_000),
                  lambda step: {"deployed_success": 0.0, "deployed_return": value, "steps_per_s": 20.0,
                                "wall_s": step / 20}, status)
    return root


def test_report_of_return_cells_speaks_returns(tmp_path, capsys):
    """`harness report suite=earl_returns`: the verdict table in returns, and the curves of kitchen's deployed return
    (every env of the suite publishes returns), not its success rate."""
    from harness.report import report_cli

    # before any run: the suite's checks, every one "not started" (what will be judged, against what band)
    (tmp_path / "results").mkdir()
    assert report_cli(["suite=earl_returns", f"results={tmp_path / 'results'}", f"out={tmp_path / 'before'}"]) == 0
    before = (tmp_path / "before" / "reproduction.md").read_text()
    assert "| risc | minitaur | 2M | 1900k-2000k | -604 (-851 to -483) | - (-, -) | not started | not started |" in before
    assert "no results for suite 'earl_returns'" in capsys.readouterr().err
    root = _write_kitchen_naive(tmp_path / "results")
    out = tmp_path / "out"
    assert report_cli(["suite=earl_returns", f"results={root}", f"out={out}", "published=none"]) == 0
    md = (out / "reproduction.md").read_text()
    assert "| naive | kitchen | 1M | 900k-1000k | -2838 (-3078 to -2727) | -2700 (-2700, -2700) | pass |" in md
    assert (out / "curves.png").exists() and (out / "reproduction.png").exists()
    from harness import report as rep

    seen = []
    real = rep.plot_curves
    rep.plot_curves = lambda curves, pub, metric: (seen.append(metric), real(curves, pub, metric))[1]
    try:
        assert report_cli(["suite=earl_returns", f"results={root}", f"out={out}", "published=none"]) == 0
        assert report_cli(["suite=earl_returns", f"results={root}", f"out={out}", "published=none",
                           "metric=deployed_success"]) == 0
    finally:
        rep.plot_curves = real
    assert seen == ["deployed_return", "deployed_success"]
    # without published=: kitchen's curves are overlaid from EARL's own numbers (source earl_benchmark)
    pubs = []
    real_select = rep.A.select
    def spy(df, metric=None, **eq):
        if "source" in eq:
            pubs.append(tuple(eq["source"]))
        return real_select(df, metric, **eq)

    rep.A.select = spy
    try:
        assert report_cli(["suite=earl_returns", f"results={root}", f"out={out}"]) == 0
    finally:
        rep.A.select = real_select
    assert pubs == [("risc_paper", "earl_benchmark")]


def test_reproduction_tab_shows_return_cells_in_return_units(monkeypatch, tmp_path):
    """kitchen's and minitaur's cells (suites/earl_returns.yaml) check the deployed return: the table says so, its
    numbers are whole returns with their bands, and each panel's y axis is the return (not success in [0, 1])."""
    pytest.importorskip("streamlit")
    from tests.test_app import run_app

    root = _write_kitchen_naive(tmp_path / "results")
    at = run_app(monkeypatch, root, "Reproduction")
    at.selectbox(key="repro_suite").set_value("earl_returns")
    at.run()
    assert not at.exception
    table = at.dataframe[0].value
    naive = table[table["method"] == "naive"].iloc[0]
    assert naive["metric"] == "deployed_return" and naive["verdict"] == "pass" and naive["ours"] == "-2700"
    assert naive["accepted"] == "-3342 to -2463" and naive["ours_per_seed"] == "-2700, -2700"
    charts = at.get("vega_lite_chart")
    assert len(charts) == 3
    import json

    def y_axes(node):  # every y encoding in the (layered) Vega-Lite spec
        if isinstance(node, dict):
            if isinstance(node.get("encoding"), dict) and "y" in node["encoding"]:
                yield node["encoding"]["y"]
            for v in node.values():
                yield from y_axes(v)
        elif isinstance(node, list):
            for v in node:
                yield from y_axes(v)

    ys = list(y_axes(json.loads(charts[1].proto.spec)))
    assert ys and all(y.get("title") == "deployed return" and y.get("scale", {}).get("domain") != [0, 1] for y in ys)


@requires_data
def test_criterion_operating_characteristics():
    """The rule's justification (docs/reproduction.md), as numbers: a faithful method passes every check with 2 seeds
    with probability >= 0.9; a method that does not learn (window mean 0.1) fails every check; RISC's VaPRL (0.97 over
    200k-300k) fails the published VaPRL's window."""
    from harness.results import load_published

    ladder = R.load_ladder("reproduction")
    oc = R.operating_characteristics(ladder, load_published(), seeds=(2,))
    assert (oc["p_pass_2_seeds"] >= 0.9).all(), oc
    assert (oc["lower"] > 0.1).all()
    vaprl = oc[(oc["method"] == "vaprl") & (oc["env"] == "tabletop_manipulation") & (oc["window"] == "200k-300k")]
    assert float(vaprl["upper"].iloc[0]) < 0.97


def test_ship_copies_tables_not_checkpoints_and_report_rewrites_the_doc_table(tmp_path):
    from harness.cli import main
    from harness.results import load

    runs = write_ladder_results(tmp_path / "runs")
    ckpt = runs / "reproduction" / "sawyer_door" / "oracle" / "checkpoints" / "seeds=0,1" / "checkpoint.pt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_bytes(b"x" * 100)
    from harness.results import TRAIN_FILE, load_train

    diag = run_dir(runs, "reproduction", "sawyer_door", "oracle", 0) / TRAIN_FILE  # training diagnostics ship too
    pd.read_parquet(run_dir(runs, "reproduction", "sawyer_door", "oracle", 0) / "evals.parquet").to_parquet(diag)
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={tmp_path / 'repo'}"]) == 0
    shipped = sorted(p.relative_to(tmp_path / "repo") for p in (tmp_path / "repo").rglob("*") if p.is_file())
    assert len(shipped) == 7 * 3 + 1 and not any("checkpoints" in p.parts for p in shipped)
    pd.testing.assert_frame_equal(load(tmp_path / "repo"), load(runs))
    pd.testing.assert_frame_equal(load_train(tmp_path / "repo"), load_train(runs))
    assert main(["ship", "suite=nope", f"results={runs}"]) == 2  # one line, nothing written
    doc = tmp_path / "doc.md"
    doc.write_text("intro\n<!-- table:reproduction -->\nold\n<!-- /table:reproduction -->\nend\n")
    assert main(["report", "suite=reproduction", f"results={runs}", f"out={tmp_path / 'out'}", f"doc={doc}",
                 "published=none"]) == 0
    text = doc.read_text()
    assert text.startswith("intro\n<!-- table:reproduction -->\n| method |") and "old" not in text
    assert text.endswith("<!-- /table:reproduction -->\nend\n") and "fail (too weak)" in text
    assert (tmp_path / "reproduction.png").is_file()
    bad = tmp_path / "nomarkers.md"
    bad.write_text("no table here\n")
    assert main(["report", "suite=reproduction", f"results={runs}", f"out={tmp_path / 'out2'}", f"doc={bad}"]) == 2
    assert not (tmp_path / "out2").exists() and bad.read_text() == "no table here\n"


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git")
def test_ship_says_when_git_ignores_where_the_tables_went(tmp_path, capsys):
    """Shipped tables are meant to be committed: into a folder the work tree ignores, ship says so and how to fix it."""
    from harness.cli import main

    runs = write_ladder_results(tmp_path / "runs")
    repo = tmp_path / "repo"
    subprocess.run(["git", "init", "-q", str(repo)], check=True)
    (repo / ".gitignore").write_text("/results/*\n!/results/reproduction/\n")
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo / 'results'}"]) == 0
    assert "ignored by git" not in capsys.readouterr().err  # un-ignored: nothing to say
    (repo / ".gitignore").write_text("/results/*\n")
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo / 'results'}", "force=true"]) == 0
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "ignored by git" in err and "'!/results/reproduction/'" in err


def test_ship_keeps_a_shipped_table_that_got_further_than_a_restarted_run(tmp_path, capsys):
    """A run restarted from 0 (its checkpoint lost with the machine) must not replace the shipped record of how far
    the lost run got, until it passes it or force=true says so."""
    from harness.cli import main
    from harness.results import load

    runs = write_ladder_results(tmp_path / "runs")
    repo = tmp_path / "repo"
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo}"]) == 0
    evals = min((runs / "reproduction").rglob("evals.parquet"))
    full = pd.read_parquet(evals)
    restarted = full[full["step"] <= full["step"].min()]  # the run starts again: its first evaluation only
    restarted.to_parquet(evals, index=False)
    capsys.readouterr()
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo}"]) == 0
    out = capsys.readouterr().out
    rel = evals.parent.relative_to(runs / "reproduction").as_posix()
    assert f"kept the shipped table of {rel} (shipped to step {int(full['step'].max()):,}" in out
    pd.testing.assert_frame_equal(pd.read_parquet(repo / "reproduction" / rel / "evals.parquet"), full)
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo}", "force=true"]) == 0
    pd.testing.assert_frame_equal(load(repo), load(runs))
    assert main(["ship", "suite=reproduction", f"results={runs}", f"to={repo}", "force=maybe"]) == 2


def test_a_shipped_unfinished_run_says_shipped_not_stale(tmp_path):
    """An unfinished run's status ships as ``shipped`` at its step (no speed, no ETA: the run goes on elsewhere), never
    ``stale`` however old the copy; a finished run's ships as it is."""
    from harness.results import RunResults, read_status, ship, write_status
    from harness.run_status import run_status, status_counts

    for seed, state in ((0, "running"), (1, "done")):
        d = run_dir(tmp_path / "runs", "s", "sawyer_door", "medal", seed)
        RunResults(d, {"suite": "s", "env": "sawyer_door", "algo": "medal", "seed": seed}, {}).append(
            0, {"deployed_success": 0.0})
        write_status(d, state=state, step=380_000, total=8_000_000, steps_per_s=34.0, eta_s=2e5, last_success=0.0,
                     updated=1.0)  # last updated long ago
    ship(tmp_path / "runs", "s", tmp_path / "repo")
    shipped = [read_status(run_dir(tmp_path / "repo", "s", "sawyer_door", "medal", s)) for s in (0, 1)]
    assert shipped[0]["state"] == "shipped" and shipped[0]["shipped_from"] == "running"
    assert shipped[0]["step"] == 380_000 and shipped[0]["eta_s"] is None and shipped[0]["steps_per_s"] is None
    assert shipped[1]["state"] == "done" and shipped[1]["eta_s"] == 2e5
    st = run_status(tmp_path / "repo")
    assert sorted(st["state"]) == ["done", "shipped"] and status_counts(st) == {"shipped": 1, "done": 1}
