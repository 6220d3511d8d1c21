"""harness.analysis (grids, curves, final performance), harness.stats (bootstrap, IQM/PoI), harness.tables (Table 1),
harness.run_status and harness.results.parse_run_dir."""

from __future__ import annotations

import itertools
import math
import time

import numpy as np
import pandas as pd
import pytest

from harness import analysis as A
from harness.labels import method_color
from harness.results import STATUS_FILE, load, parse_run_dir, read_status, run_dir
from harness.run_status import format_duration, run_status, status_counts
from harness.stats import (
    aggregate_scores,
    bootstrap_mean_ci,
    iqm,
    no_shared_env,
    probability_of_improvement,
    stratified_bootstrap,
)
from harness.tables import PUBLISHED_TABLE1, table1, table1_csv, table1_latex, table1_markdown
from tests import fixtures_results as F


@pytest.fixture(scope="module")
def fixture_dir(tmp_path_factory):
    return F.write_fixture(tmp_path_factory.mktemp("results"), corrupt=True, tuning=False)


@pytest.fixture(scope="module")
def df(fixture_dir):
    return load(fixture_dir, warn=lambda m: None)


def long(runs: dict[int, dict[int, float]], env="e", algo="a", metric="deployed_success") -> pd.DataFrame:
    rows = [{"suite": "s", "env": env, "algo": algo, "seed": seed, "step": step, "metric": metric, "value": v,
             "source": "harness"} for seed, pts in runs.items() for step, v in pts.items()]
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------- aggregates


def test_iqm_hand_computed():
    assert iqm(np.arange(1, 9)) == pytest.approx(4.5)  # drop 1,2 and 7,8 -> mean(3,4,5,6)
    assert iqm([4, 1, 3, 2]) == pytest.approx(2.5)  # drop 1 and 4
    assert iqm([1, 2, 3]) == pytest.approx(2.0)  # int(0.75) = 0 dropped -> plain mean
    x = np.random.default_rng(1).random((7, 13))
    from scipy.stats import trim_mean

    assert iqm(x, axis=1) == pytest.approx(trim_mean(x, 0.25, axis=1))


def test_stratified_bootstrap_resamples_within_tasks():
    # task A all 0, task B all 1, 2 runs each: every stratified resample holds exactly two 0s and
    # two 1s, so the IQM (mean of the middle two) is 0.5 in every resample; a pooled bootstrap would vary.
    point, lo, hi = stratified_bootstrap([np.zeros(2), np.ones(2)], iqm, reps=500, seed=0)
    assert (point, lo, hi) == (0.5, 0.5, 0.5)


def test_stratified_bootstrap_matches_exact_enumeration():
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    exact = np.array([np.mean(s) for s in itertools.product(x, repeat=5)])  # all 5^5 resamples
    e_lo, e_hi = np.percentile(exact, [2.5, 97.5])
    point, lo, hi = stratified_bootstrap([x], np.mean, reps=20000, seed=0)
    assert point == pytest.approx(2.0)
    assert lo == pytest.approx(e_lo, abs=0.2) and hi == pytest.approx(e_hi, abs=0.2)
    assert stratified_bootstrap([x], np.mean, reps=500, seed=3) == stratified_bootstrap([x], np.mean, reps=500,
                                                                                              seed=3)


def test_probability_of_improvement_hand_computed():
    # X=[1,2,3] vs Y=[2,2,0]: 5 pairs X>Y, 2 ties, of 9 -> (5 + 0.5*2)/9 = 2/3
    p, lo, hi = probability_of_improvement([[1, 2, 3]], [[2, 2, 0]], reps=1000)
    assert p == pytest.approx(2 / 3) and lo <= p <= hi
    # a second task where X always loses (0 vs 1): average over tasks = (2/3 + 0)/2
    p, _, _ = probability_of_improvement([[1, 2, 3], [0, 0]], [[2, 2, 0], [1]], reps=200)
    assert p == pytest.approx(1 / 3)
    assert probability_of_improvement([[0.5, 0.5]], [[0.5]], reps=100) == (0.5, 0.5, 0.5)


def test_aggregate_scores_fixture(df):
    scores = A.final_scores(df)
    agg = aggregate_scores(scores, reps=500).set_index("algo")
    for algo in F.ALGOS:
        pooled = scores.loc[scores["algo"] == algo, "score"].to_numpy()
        assert agg.loc[algo, "iqm"] == pytest.approx(iqm(pooled))
        assert agg.loc[algo, "mean"] == pytest.approx(pooled.mean())
        assert agg.loc[algo, "iqm_lo"] <= agg.loc[algo, "iqm"] <= agg.loc[algo, "iqm_hi"]
        assert agg.loc[algo, "n_envs"] == 2 and agg.loc[algo, "n_runs"] == 6


def test_without_a_shared_env_the_aggregates_say_which_methods_each_env_lacks():
    scores = pd.DataFrame({"env": ["sawyer_door", "sawyer_door", "sawyer_peg"], "algo": ["medal", "naive", "fbrl"],
                           "seed": [0, 0, 0], "score": [1.0, 0.0, 0.5]})
    assert aggregate_scores(scores, reps=10).empty
    assert no_shared_env(scores, ["naive", "medal", "fbrl"]) == \
        "sawyer_door: lacks FBRL; sawyer_peg: lacks naive RL, MEDAL"


# ---------------------------------------------------------------------------- curves


def test_learning_curves_equal_pandas(df):
    c = A.learning_curves(df, "deployed_success")
    ours = df[df["metric"] == "deployed_success"]
    direct = ours.groupby(["env", "algo", "step"])["value"].agg(["mean", "sem", "size"]).reset_index()
    m = c.merge(direct, on=["env", "algo", "step"])
    assert len(m) == len(direct) == len(c)
    np.testing.assert_allclose(m["mean_x"], m["mean_y"])
    np.testing.assert_allclose(m["se"], m["sem"])
    assert (m["n"] == 3).all() and set(c["grid"]) == {"common"}
    mean, se = F.expected_final("sawyer_door", "medal")
    last = c[(c["env"] == "sawyer_door") & (c["algo"] == "medal") & (c["step"] == F.STEPS)].iloc[0]
    assert (last["mean"], last["se"]) == (pytest.approx(mean), pytest.approx(se))


def test_bootstrap_ci_seeded_and_sane(df):
    a = A.learning_curves(df, ci=True, n_boot=300, seed=0)
    b = A.learning_curves(df, ci=True, n_boot=300, seed=0)
    pd.testing.assert_frame_equal(a, b)
    assert (a["ci_lo"] <= a["mean"] + 1e-12).all() and (a["mean"] <= a["ci_hi"] + 1e-12).all()
    lo, hi = bootstrap_mean_ci(np.full((2, 4), 0.3))
    np.testing.assert_allclose([lo, hi], 0.3)


def test_common_grid_intersection_and_interpolation():
    d = long({0: {0: 0.0, 10: 1.0, 20: 2.0, 30: 3.0}, 1: {0: 0.0, 10: 1.0, 20: 2.0}})
    a = A.aligned(d, "deployed_success")
    assert sorted(a["step"].unique()) == [0, 10, 20] and set(a["grid"]) == {"common"}
    # evaluated at different steps: interpolate onto the union inside the range both cover [5, 25]
    d = long({0: {0: 0.0, 10: 10.0, 20: 20.0, 30: 30.0}, 1: {5: 1.0, 15: 3.0, 25: 5.0}})
    c = A.learning_curves(d)
    assert list(c["step"]) == [5, 10, 15, 20, 25] and set(c["grid"]) == {"interp"}
    np.testing.assert_allclose(c["mean"], [(5 + 1) / 2, (10 + 2) / 2, (15 + 3) / 2, (20 + 4) / 2, (25 + 5) / 2])
    c = A.learning_curves(d, grid="common")
    assert c.empty  # no step is shared


def test_smoothing_trailing_moving_average():
    d = long({0: {0: 0.0, 1: 3.0, 2: 6.0, 3: 9.0}})
    c = A.learning_curves(d, window=2)
    np.testing.assert_allclose(c["mean"], [0.0, 1.5, 4.5, 7.5])
    s = A.smooth(d, 3)
    np.testing.assert_allclose(s.sort_values("step")["value"], [0.0, 1.5, 3.0, 6.0])


def test_tuning_rows_and_trial_runs(tmp_path):
    d = load(F.write_fixture(tmp_path, tuning=True), warn=lambda m: None)
    tun = A.is_tuning(d)
    assert set(d.loc[tun, "suite"]) == {f"tune_{F.TUNE_STUDY}"} and not d.loc[~tun, "study"].notna().any()
    runs = A.with_runs(d[tun])["run"].unique()
    assert list(runs) == [f"tune_{F.TUNE_STUDY}/0/trial=0"]
    st = run_status(tmp_path)
    assert st["tuning"].sum() == 1 and st.loc[st["tuning"], "suite"].iloc[0].startswith("tuning/")


def test_derived_continuing_rate(df):
    d = A.derive_metrics(df)
    r = d[d["metric"] == "continuing_reward_rate"]
    assert len(r) and (r["step"] > 0).all()
    cr = df[(df["metric"] == "continuing_reward") & (df["step"] > 0)]
    np.testing.assert_allclose(np.sort(r["value"].to_numpy()), np.sort((cr["value"] / cr["step"]).to_numpy()))


# ---------------------------------------------------------------------------- final performance, Table 1


def test_final_performance_last_matched_and_step(df):
    fp = A.final_performance(df).set_index(["env", "algo"])
    for env in F.ENVS:
        for algo in F.ALGOS:
            mean, se = F.expected_final(env, algo)
            assert fp.loc[(env, algo), "mean"] == pytest.approx(mean)
            assert fp.loc[(env, algo), "se"] == pytest.approx(se)
            assert fp.loc[(env, algo), "n"] == 3
    at = A.final_performance(df, step=55_000).set_index(["env", "algo"])  # last eval at or before: 50k
    assert at.loc[("sawyer_door", "medal"), "mean"] == pytest.approx(0.7 * 0.5 + 0.1)
    assert at.loc[("sawyer_door", "medal"), "step"] == 50_000
    k2 = A.final_performance(df, last_k=2).set_index(["env", "algo"])  # mean of 90k and 100k
    assert k2.loc[("sawyer_door", "medal"), "mean"] == pytest.approx(0.7 * 0.95 + 0.1)
    # one run stops at 60k: "matched" cuts every run in that env at 60k, "last" does not
    short = df[~((df["algo"] == "naive") & (df["env"] == "sawyer_door") & (df["seed"] == 0) & (df["step"] > 60_000))]
    assert A.matched_steps(short) == {"sawyer_door": 60_000, "tabletop_manipulation": F.STEPS}
    m = A.final_performance(short, step="matched").set_index(["env", "algo"])
    assert m.loc[("sawyer_door", "medal"), "mean"] == pytest.approx(0.7 * 0.6 + 0.1)
    assert m.loc[("tabletop_manipulation", "medal"), "mean"] == pytest.approx(0.7)
    beyond = A.final_performance(short, step=80_000).set_index(["env", "algo"])
    assert beyond.loc[("sawyer_door", "naive"), "n"] == 2  # the short run did not reach 80k


def test_table1_beside_published(df):
    t = table1(df)
    r = t.set_index(["algo", "env"])
    mean, se = F.expected_final("tabletop_manipulation", "medal")
    assert r.loc[("medal", "tabletop_manipulation"), "ours_mean"] == pytest.approx(mean)
    assert r.loc[("medal", "tabletop_manipulation"), "paper_mean"] == 0.98
    assert r.loc[("medal", "tabletop_manipulation"), "diff"] == pytest.approx(mean - 0.98)
    assert r.loc[("medal", "tabletop_manipulation"), "ours_best"]
    assert not r.loc[("naive", "tabletop_manipulation"), "ours_best"]
    # paper ties are all bold: VaPRL and MEDAL on tabletop, FBRL/MEDAL/oracle on door
    assert set(t[t["paper_best"] & (t["env"] == "tabletop_manipulation")]["algo"]) == {"vaprl", "medal"}
    assert set(t[t["paper_best"] & (t["env"] == "sawyer_door")]["algo"]) == {"fbrl", "medal", "oracle"}
    assert set(t["env"]) == set(F.ENVS)  # only envs we have results for
    assert np.isnan(r.loc[("fbrl", "sawyer_door"), "ours_mean"])  # paper-only row
    md = table1_markdown(t)
    # at 100k of the 3M Table-1 budget: marked with its step, and the note says why
    assert "| MEDAL | **0.70 (0.06)** @100k† | **0.98 (0.02)** | -0.28 |" in md
    assert md.rstrip().endswith("not a final number.") and "(3M tabletop organization, 5M sawyer door, 8M" in md
    tex = table1_latex(t)
    assert r"\textbf{0.70 (0.06)} @100k$^\dagger$" in tex and r"\begin{tabular}" in tex and "_" not in tex.replace(r"\_", "")
    back = pd.read_csv(__import__("io").StringIO(table1_csv(t)))
    assert list(back.columns) == list(t.columns) and len(back) == len(t)
    ours_only = table1(df, published=None)
    assert set(ours_only["algo"]) == set(F.ALGOS)
    assert "paper" not in table1_markdown(ours_only, published=False)


def test_published_table_is_section_15():
    assert len(PUBLISHED_TABLE1) == 18
    assert PUBLISHED_TABLE1[("medal", "sawyer_peg")] == (0.40, 0.16)
    assert PUBLISHED_TABLE1[("r3l", "sawyer_door")] == (0.54, 0.18)


# ---------------------------------------------------------------------------- status


def test_run_status(fixture_dir):
    st = run_status(fixture_dir)
    by = st.set_index(["env", "algo", "seed"])
    assert by.loc[("sawyer_door", "medal_logc", 0), "state"] == "running"
    assert by.loc[("sawyer_door", "medal_logc", 1), "state"] == "resumed"
    assert by.loc[("sawyer_door", "medal_logc", 2), "state"] == "stale"
    assert by.loc[("sawyer_door", "fbrl", 0), "state"] == "failed"
    assert by.loc[("sawyer_door", "fbrl", 0), "error"] == F.FAILED_ERROR  # first line only
    assert by.loc[("sawyer_door", "broken", 0), "state"] == "unknown"  # corrupt parquet, no status
    assert by.loc[("tabletop_manipulation", "medal", 1), "last_success"] == pytest.approx(0.7)
    assert status_counts(st) == {"running": 1, "resumed": 1, "stale": 1, "done": 15, "failed": 1, "unknown": 1}
    later = run_status(fixture_dir, now=time.time() + 10 * 3600)
    assert (later["state"] == "stale").sum() == 3  # running and resumed ones go stale too
    assert format_duration(3725) == "1h02m" and format_duration(math.inf) == "?"


def test_harness_status_prints_every_run_with_its_progress(fixture_dir, tmp_path, capsys):
    """`harness status`: one line per run (state, step of total, speed and ETA while running, last success), the
    error line of a failed run, and a count per state; suite= filters; a missing directory is one error line."""
    from harness.cli import main

    assert main(["status", f"results={fixture_dir}"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["suite", "env", "algo", "seed", "state", "step", "of", "%", "steps/s", "ETA", "success",
                              "updated"]
    st = run_status(fixture_dir)
    assert len([line for line in out[1:] if not line.startswith("  ")]) == len(st) + 1
    assert out[-1] == f"{len(st)} run(s): 1 running, 1 resumed, 1 stale, 15 done, 1 failed, 1 unknown"
    assert any(F.FAILED_ERROR in line for line in out if line.startswith("  "))
    running = next(r for r in st.itertuples() if r.state == "running")
    line = next(x for x in out if x.split()[4:5] == ["running"])
    assert f"{running.step:,.0f}" in line and format_duration(running.eta_s) in line
    assert main(["status", f"results={fixture_dir}", "suite=FIXTURE"]) == 0  # any case
    assert len(capsys.readouterr().out.splitlines()) > 3
    assert main(["status", f"results={fixture_dir}", "suite=fixtur"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("harness: error: no runs of suite 'fixtur'") and "(did you mean fixture?)" in err
    assert main(["status", f"results={tmp_path / 'none'}"]) == 2
    assert capsys.readouterr().err.strip().startswith("harness: error: results directory not found")


def test_parse_run_dir_inverts_run_dir(tmp_path):
    for suite, env, algo, seed in [("main", "sawyer_door", "medal", 0), ("tuning/s/trial=3/tune_s", "e", "a", 12)]:
        d = run_dir(tmp_path, suite, env, algo, seed)
        ident = parse_run_dir(d, tmp_path)
        assert ident == {"suite": suite, "env": env, "algo": algo, "seed": seed}
        assert run_dir(tmp_path, **ident) == d
    assert parse_run_dir(tmp_path / "main" / "e" / "a" / "checkpoints", tmp_path) is None
    assert parse_run_dir(tmp_path, tmp_path) is None
    # read below the results root (a suite's folder): what lies above it is unknown
    assert parse_run_dir(tmp_path / "e" / "a" / "seed=1", tmp_path) == {"suite": None, "env": "e", "algo": "a",
                                                                         "seed": 1}


def test_run_status_names_an_unreadable_status_file(tmp_path):
    for seed, text in ((0, "{not json"), (1, "[1, 2]")):
        d = run_dir(tmp_path, "s", "e", "a", seed)
        d.mkdir(parents=True)
        (d / STATUS_FILE).write_text(text)
    st = run_status(tmp_path).set_index("seed")
    assert (st["state"] == "unknown").all()
    assert st.loc[0, "error"].startswith("unreadable status.json: JSONDecodeError")
    assert st.loc[1, "error"] == "status.json is not a JSON object"
    assert read_status(run_dir(tmp_path, "s", "e", "a", 0)) is None  # the lenient reader

def test_published_overlay_keeps_only_our_env_algo_pairs():
    """Oracle run on door only and RISC on tabletop only: the paper's RISC-on-door and oracle-on-tabletop curves
    are not drawn beside them."""
    ours = pd.concat([long({0: {10: 0.0}}, env="door", algo="oracle"), long({0: {10: 0.0}}, env="table", algo="risc")])
    pub = pd.concat([long({0: {10: 1.0}}, env=e, algo=a) for e in ("door", "table", "peg") for a in ("oracle", "risc")])
    kept = A.same_pairs(pub, ours)
    assert sorted(zip(kept.env, kept.algo)) == [("door", "oracle"), ("table", "risc")]
    assert A.same_pairs(pub.iloc[:0], ours).empty


def test_every_method_has_its_own_fixed_colour_in_report_and_dashboard():
    """13+ methods, one colour each, the same in `harness report` and app.py (the published RISC ablation shares
    risc_no_tab's colour: it is the same method); variants get a stable colour by name."""
    from harness.registry import ALGORITHMS
    from harness.report import algo_colors

    names = list(ALGORITHMS) + ["risc_no_switching"]
    colors = algo_colors(names)
    assert len(set(colors.values())) == len(names) >= 15
    assert method_color("risc_no_timeout_bootstrap") == colors["risc_no_tab"]
    assert method_color("vaprl_risc_no_tab") == method_color("vaprl_risc_no_tab")  # stable for variants
    # names whose own colour collides (crc32 % 8: "medal · table1" and "risc · reproduction" both 6) still get two
    # colours in one figure, and the registered methods beside them keep theirs
    clash = ["medal", "medal · table1", "risc · reproduction", "medal · reproduction", "vaprl_demo_relabel"]
    assert method_color(clash[1]) == method_color(clash[2]) and method_color(clash[3]) == method_color(clash[4])
    shown = algo_colors(clash)
    assert len(set(shown.values())) == len(clash) and shown["medal"] == colors["medal"]
    assert algo_colors(clash[1:2])[clash[1]] == method_color(clash[1])  # alone, a name keeps its own colour


def test_runs_of_different_suites_are_never_pooled_as_seeds():
    """Issue 58: a 400-step smoke seed beside three 1.5M ladder seeds of one method are two rows and two curves, each
    at its own step, the paper's number beside both; a method from one suite keeps its name."""
    def runs(suite, seeds, last, value, algo="medal"):
        return pd.concat([long({s: {0: 0.0, last: value}}, "tabletop_manipulation", algo).assign(suite=suite, seed=s)
                          for s in seeds], ignore_index=True)

    df = pd.concat([runs("smoke", [0], 400, 0.0), runs("reproduction", [0, 1, 2], 1_500_000, 1.0),
                    runs("reproduction", [0], 300_000, 1.0, algo="risc")], ignore_index=True)
    d = A.separate_suites(df)
    assert set(d["algo"]) == {"medal · smoke", "medal · reproduction", "risc"}
    assert A.base_algo("medal · smoke") == "medal" and A.base_algo("risc") == "risc"
    t = table1(d).set_index("algo")
    assert t.loc["medal · reproduction", ["ours_mean", "n", "step"]].tolist() == [1.0, 3, 1_500_000]
    assert t.loc["medal · smoke", ["ours_mean", "n", "step"]].tolist() == [0.0, 1, 400]
    assert t.loc["medal · smoke", "paper_mean"] == t.loc["medal · reproduction", "paper_mean"] == 0.98
    assert "medal" not in t.index  # no pooled row
    md = table1_markdown(table1(d))
    assert "| MEDAL · reproduction | **1.00 (0.00)** @1.5M | **0.98 (0.02)** |" in md
    assert "| MEDAL · smoke | 0.00 (1 seed) @400† |" in md
    c = A.learning_curves(d, "deployed_success")
    assert c[c["algo"] == "medal · reproduction"]["step"].max() == 1_500_000  # not cut to the smoke run's 400
    from harness.labels import algo_label, method_color

    assert algo_label("medal · smoke") == "MEDAL · smoke"
    assert method_color("medal · smoke") != method_color("medal · reproduction")


def test_loading_a_mistyped_path_says_so(tmp_path):
    """`harness.results.load` of a path that does not exist: the empty table, and a warning naming the path (a typo
    is not "no results yet"); an existing empty directory is quiet."""
    from harness.results import COLUMNS, load

    said = []
    df = load(tmp_path / "reslts", warn=said.append)
    assert df.empty and list(df.columns)[: len(COLUMNS)] == COLUMNS
    assert len(said) == 1 and f"no results directory {tmp_path / 'reslts'}" in said[0]
    said.clear()
    assert load(tmp_path, warn=said.append).empty and said == []
