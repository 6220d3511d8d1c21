"""The whole-curve checks (harness/curve_checks.py): every 100k window against the published per-seed range with an
allowance computed from a faithful method's false-fail probability, and the first-success step; the pre-registered
Table-1 suite; the Table-1 evidence grid (harness/evidence.py)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from harness import curve_checks as C
from harness import reproduction as R
from harness.synthetic import write_run

from .conftest import requires_data

STEPS = 500_000


def curve(fn, seed: int, steps: int = STEPS) -> pd.DataFrame:
    """One seed's curve, evaluations at 0 and every 10k: value fn(step)."""
    s = np.arange(0, steps + 1, 10_000)
    return pd.DataFrame({"seed": seed, "step": s, "value": [float(fn(x)) for x in s]})


def ramp(at: int, top: float = 1.0):
    """0 until step ``at``, ``top`` from there."""
    return lambda s: top if s >= at else 0.0


def published_five(starts=(200_000, 230_000, 260_000, 290_000, 320_000)) -> pd.DataFrame:
    """Five published seeds that jump from 0 to 1 at ``starts``."""
    return pd.concat([curve(ramp(a), k) for k, a in enumerate(starts)], ignore_index=True)


def test_window_table_and_bands_use_complete_windows_only():
    pub = published_five()
    t = C.window_table(pub, STEPS)
    assert list(t.index) == [0, 100_000, 200_000, 300_000, 400_000]
    # seed 1 (1.0 from 230k): window 200k-300k holds 210k..300k, 8 of its 10 evaluations at 1
    assert t.loc[200_000, 1] == pytest.approx(0.8) and t.loc[0, 1] == 0.0
    short = pub[~((pub["seed"] == 4) & (pub["step"] == 450_000))]  # seed 4 misses one evaluation of the last window
    b = C.published_bands(short, STEPS, 0.1)
    assert b.loc[400_000, "seeds"] == 4 and b.loc[300_000, "seeds"] == 5
    assert b.loc[200_000, ["min", "max", "lower", "upper"]].tolist() == pytest.approx([0.0, 1.0, -0.1, 1.1])
    assert b.loc[300_000, ["min", "upper"]].tolist() == pytest.approx([0.9, 1.1])  # seed 4: 320k..400k at 1
    only_two = pub[pub["seed"] < 2]  # fewer than 3 complete seeds: no window is checked
    assert C.published_bands(only_two, STEPS, 0.1).empty


def test_faithful_method_passes_a_fast_or_a_flat_one_fails():
    pub = published_five()
    a, p = C.allowance(pub, STEPS, 2)
    assert 0 <= a <= 1 and p <= 0.05
    # our seeds follow two published seeds: every window in band
    ours = pd.concat([curve(ramp(230_000), 0), curve(ramp(290_000), 1)], ignore_index=True)
    v = C.whole_curve_verdict(ours, pub, STEPS, (0, 1))
    assert v["status"] == "pass" and v["out"] == [] and v["first_success_status"] == "pass"
    assert v["first_success"] == [230_000, 290_000] and "pass" in C.whole_curve_text(v)
    # learning at 60k and 80k: windows 0-100k and 100k-200k are far above the published 0.0 (band upper 0.1)
    fast = pd.concat([curve(ramp(60_000), 0), curve(ramp(80_000), 1)], ignore_index=True)
    v = C.whole_curve_verdict(fast, pub, STEPS, (0, 1))
    assert v["status"] == "fail" and v["out"] == [(0, "high"), (100_000, "high")]
    assert C.whole_curve_text(v).startswith("fail: 2 of 5 windows out") and "too strong at 0k-100k, 100k-200k" in \
        C.whole_curve_text(v)
    assert v["first_success_status"] == "fail" and C.first_success_text(v).startswith("fail (too early)")
    # never learns: the last windows are below every published seed; first success never (budget + 10k)
    flat = pd.concat([curve(ramp(10**9), 0), curve(ramp(10**9), 1)], ignore_index=True)
    v = C.whole_curve_verdict(flat, pub, STEPS, (0, 1))
    assert v["status"] == "fail" and (300_000, "low") in v["out"] and (400_000, "low") in v["out"]
    assert v["first_success"] == [None, None] and v["first_success_mean"] == STEPS + 10_000
    assert C.first_success_text(v).startswith("fail (too late): ours never, never")


def test_the_faithful_methods_numbers_are_computed_once_per_machine(monkeypatch):
    """The allowance and the first-success band (Monte Carlo over the published seeds, seconds for Table 1) are kept
    on disk: a new process (the memo emptied) reads them back equal, without computing; other published values, or
    other arguments, are computed."""
    pub = published_five()
    monkeypatch.setattr(C, "_MEMO", {})  # as a new process: what earlier tests computed is not in this one's state
    a = C.allowance(pub, STEPS, 2)
    band = C.first_success_band(pub, STEPS)
    monkeypatch.setattr(C, "_MEMO", {})
    monkeypatch.setattr(C, "_allowance", lambda *a: pytest.fail("computed again"))
    monkeypatch.setattr(C, "_first_success_band", lambda *a: pytest.fail("computed again"))
    assert C.allowance(pub, STEPS, 2) == a and isinstance(C.allowance(pub, STEPS, 2), tuple)
    assert C.first_success_band(pub, STEPS) == band
    with pytest.raises(pytest.fail.Exception, match="computed again"):
        C.allowance(pub, STEPS, 3)
    with pytest.raises(pytest.fail.Exception, match="computed again"):
        C.allowance(pub.assign(value=pub["value"] * 0.9), STEPS, 2)


def test_running_checks_wait_unless_nothing_to_come_can_turn_them():
    pub = published_five()
    ours = pd.concat([curve(ramp(230_000), 0, 150_000), curve(ramp(290_000), 1, 150_000)], ignore_index=True)
    v = C.whole_curve_verdict(ours, pub, STEPS, (0, 1))
    assert v["status"] == "running" and v["reached"] == 150_000 and v["first_success_status"] == "running"
    assert C.whole_curve_text(v).startswith("running (at 150,000): 0 of 5 windows out")
    # already two windows out with none allowed past 1: fail before the budget
    fast = pd.concat([curve(ramp(60_000), 0, 200_000), curve(ramp(80_000), 1, 200_000)], ignore_index=True)
    a, _ = C.allowance(pub, STEPS, 2)
    v = C.whole_curve_verdict(fast, pub, STEPS, (0, 1))
    assert (v["status"] == "fail") == (a < 2)
    # both seeds succeeded by 80k: the first-success mean is known, and too early, whatever comes
    assert v["first_success_status"] == "fail"
    one = C.whole_curve_verdict(ours[ours["seed"] == 0], pub, STEPS, (0, 1))  # seed 1 not started yet
    assert C.whole_curve_text(one).startswith("running (at 0-150,000)")
    # no success yet at 300k, and every later first success (or none) keeps the seed-mean inside a wide band: the check
    # passes before the budget, and the running seeds read "none yet", not "never" (found on oracle tabletop at 190k)
    late = published_five((150_000, 300_000, 400_000, 450_000, 10**9))
    idle = pd.concat([curve(ramp(10**9), 0, 300_000), curve(ramp(10**9), 1, 300_000)], ignore_index=True)
    v = C.whole_curve_verdict(idle, late, STEPS, (0, 1))
    lo, hi = v["first_success_band"]
    if lo <= 310_000 and hi >= STEPS + 10_000:  # decided: whatever comes lies in the band
        assert v["first_success_status"] == "pass"
    assert "ours none yet, none yet" in C.first_success_text(v) and "never" not in C.first_success_text(v)
    # no seed started: nothing to say yet
    none = C.whole_curve_verdict(ours.iloc[:0], pub, STEPS, (0, 1))
    assert C.whole_curve_text(none) == "not started" and C.first_success_text(none).startswith("not started")


def test_first_success_band_censors_and_widens_until_a_faithful_method_passes():
    pub = published_five((100_000, 200_000, 300_000, 400_000, 10**9))  # seed 4 never within the budget
    b = C.first_success_band(pub, STEPS, n=2)
    assert sorted(b["published"]) == [100_000, 200_000, 300_000, 400_000, STEPS + 10_000]
    assert b["widen"] >= 50_000 and b["widen"] % 10_000 == 0 and b["p_false_fail"] <= 0.05
    assert b["lower"] == 100_000 - b["widen"] and b["upper"] == STEPS + 10_000 + b["widen"]
    # memoised: the same published curves give the same object without recomputing
    assert C.first_success_band(pub, STEPS, n=2) is b


@requires_data
def test_table1_suite_is_the_pre_registered_rule_on_the_published_data():
    """The Table-1 suite's criterion and the numbers its verdicts rest on, as pre-registered (suites/table1.yaml)."""
    from harness.results import load_published

    ladder = R.load_ladder("table1")
    assert (ladder.widen, ladder.rule.alpha, ladder.rule.fs_widen) == (0.1, 0.05, 50_000)
    assert len(ladder.cells) == 11 and all(len(c.seeds) == 2 for c in ladder.cells)
    pub = load_published()
    got = {}
    for cell in ladder.cells:
        p = R.cell_published(pub, cell)
        got[(cell.algo, cell.env)] = (cell.steps, *C.allowance(p, cell.steps, 2))
        for check in cell.checks:  # the final window is the budget's last 100k (and MEDAL peg's 6.5M-6.6M)
            assert check.hi == cell.steps or (cell.algo, check.lo) == ("medal", 6_500_000)
    # budgets and whole-curve allowances for 2 seeds (docs/reproduction.md, "Table 1: the pre-registered cells")
    assert got[("medal", "sawyer_peg")][:2] == (8_000_000, 4)
    assert got[("r3l", "sawyer_door")][:2] == (2_500_000, 2)
    assert got[("fbrl", "sawyer_door")][:2] == (900_000, 1)
    assert all(p <= 0.05 for _, _, p in got.values())
    # every cell but the six "learns too much only" ones has a final window whose band excludes 0
    one_sided = {(c.algo, c.env) for c in ladder.cells if c.checks[-1].min - ladder.widen < 0}
    assert one_sided == {("naive", "tabletop_manipulation"), ("naive", "sawyer_door"), ("naive", "sawyer_peg"),
                         ("fbrl", "sawyer_peg"), ("r3l", "sawyer_peg"), ("vaprl", "sawyer_peg")}


@requires_data
def test_table1_evidence_marks_verified_failing_and_missing_cells(tmp_path):
    """Each cell's verdicts, and how many of its seeds have their training diagnostics shipped beside them."""
    from harness.evidence import evidence_markdown, table1_evidence
    from harness.results import load, load_published, runs_holding

    status = {"state": "done", "step": 500_000, "total": 500_000, "steps_per_s": 20.0, "eta_s": 0.0, "last_success": 1}
    pub = load_published()
    oracle = R.published_curves(pub, R.Check(0, 0, "risc_paper", "oracle", 0, 0, 0), "tabletop_manipulation")
    # oracle/tabletop (suite table1) as two published seeds did: verified; naive/peg learning at once: fails
    for s, src in ((0, 1), (1, 3)):
        c = oracle[(oracle["seed"] == src) & (oracle["step"] <= 500_000)].set_index("step")["value"]
        write_run(tmp_path, "table1", "tabletop_manipulation", "oracle", s, range(0, 500_001, 10_000),
                  lambda step, c=c: {"deployed_success": float(c.get(step, 0.0))}, status)
        write_run(tmp_path, "table1", "sawyer_peg", "naive", s, range(0, 500_001, 10_000),
                  lambda step: {"deployed_success": 1.0 if step >= 100_000 else 0.0}, status)
    (tmp_path / "table1/tabletop_manipulation/oracle/seed=0/train.parquet").write_bytes(b"")  # one seed's diagnostics
    train = runs_holding(tmp_path)
    assert train == {("table1", "tabletop_manipulation", "oracle", 0)}
    e = table1_evidence(load(tmp_path), pub, train).set_index(["algo", "env"])
    assert len(e) == 18
    assert e.loc[("oracle", "tabletop_manipulation"), "evidence"] == "verified"
    assert e.loc[("oracle", "tabletop_manipulation"), "train_tables"] == 1
    assert e.loc[("naive", "sawyer_peg"), "train_tables"] == 0
    assert e.loc[("naive", "sawyer_peg"), "evidence"] == "fails"
    assert "too strong" in e.loc[("naive", "sawyer_peg"), "windows"]
    assert e.loc[("medal", "sawyer_peg"), "evidence"] == "no results"
    md = evidence_markdown(e.reset_index())
    assert "**verified** (2 seeds, 0.5M)" in md and "no results (table1, 8M)" in md
    assert "training tables: 1 of 2 seeds" in md and "training tables: 0 of 2 seeds" in md


def test_gaps_are_not_evidence_and_no_published_curves_is_said():
    """A published seed with missing evaluations before its first success is left out of the first-success range (a
    gap is not 'no success yet'); a finished run with a missing evaluation in a checked window is not 'in band'."""
    pub = published_five()
    gap = pub[~((pub["seed"] == 4) & pub["step"].between(100_000, 300_000))]  # seed 4: nothing from 100k to 300k
    assert list(C.first_success(gap, STEPS).index) == [0, 1, 2, 3]
    ours = pd.concat([curve(ramp(230_000), 0), curve(ramp(290_000), 1)], ignore_index=True)
    holed = ours[~((ours["seed"] == 1) & (ours["step"] == 150_000))]
    v = C.whole_curve_verdict(holed, pub, STEPS, (0, 1))
    assert v["status"] == "running" and v["reached"] == STEPS
    with pytest.raises(ValueError, match="no published curves"):
        C.whole_curve_verdict(ours, pub.iloc[:0], STEPS, (0, 1))


@requires_data
def test_evidence_survives_a_check_decided_before_its_window_is_full(tmp_path):
    from harness.evidence import evidence_markdown, table1_evidence
    from harness.results import load, load_published

    status = {"state": "running", "step": 450_000, "total": 500_000, "steps_per_s": 20.0, "eta_s": 0.0,
              "last_success": 1}
    for s in (0, 1):  # naive on peg at 1.0 from 100k: its 400k-500k check already fails, whatever comes
        write_run(tmp_path, "table1", "sawyer_peg", "naive", s, range(0, 450_001, 10_000),
                  lambda step: {"deployed_success": 1.0 if step >= 100_000 else 0.0}, status)
    e = table1_evidence(load(tmp_path), load_published()).set_index(["algo", "env"])
    assert e.loc[("naive", "sawyer_peg"), "evidence"] == "fails"
    assert "whatever the rest scores" in e.loc[("naive", "sawyer_peg"), "windows"]
    md = evidence_markdown(e.reset_index())
    assert "400k-500k running" in md and "training tables" not in md  # not asked: not said


def returns_five(levels=(-900.0, -700.0, -2200.0, -500.0, 100.0), start=-2700.0, at=300_000) -> pd.DataFrame:
    """Five published seeds of a return metric: ``start`` (doing nothing) until ``at``, then their own level."""
    return pd.concat([curve(lambda s, lv=lv: lv if s >= at else start, k, 1_000_000) for k, lv in enumerate(levels)],
                     ignore_index=True)


def test_return_cells_check_in_return_units_without_success_bounds(tmp_path):
    """kitchen and minitaur publish returns: a cell there needs its own widen (return units), its window model is a
    Normal, its running final-window check is never decided early (a return has no bounds) and it has no
    first-success check."""
    suite = tmp_path / "returns.yaml"
    suite.write_text("seeds: 2\ncells: [{algo: oracle, env: kitchen, steps: 1000000, checks: [{window: [900000, 1000000], "
                     "published: {source: src, mean: -840, min: -2200, max: 100}}]}]\n")
    with pytest.raises(R.ConfigError, match="kitchen's published curves are deployed_return: give the cell its own"):
        R.load_ladder(str(suite))
    suite.write_text(suite.read_text().replace("steps: 1000000,", "steps: 1000000, widen: 264,"))
    ladder = R.load_ladder(str(suite))
    cell = ladder.cells[0]
    assert cell.metric == "deployed_return" and not cell.bounded and ladder.widen_of(cell) == 264
    assert ladder.rule_of(cell).widen == 264 and not ladder.rule_of(cell).bounded
    check = cell.checks[0]
    flat = lambda level: pd.concat([curve(lambda s: level, k, 1_000_000) for k in (0, 1)])  # noqa: E731
    v = R.verdict(flat(-2400.0), cell, check, 264)  # band [-2464, 364]
    assert v["status"] == "pass" and (v["lower"], v["upper"]) == (-2464, 364)
    assert R.verdict(flat(-2500.0), cell, check, 264)["status"] == "fail"
    assert R.verdict_text(R.verdict(flat(500.0), cell, check, 264), check, cell.steps) == "fail (too strong)"
    # nine of ten window evaluations at -2600: a success rate would be decided, a return waits for the last one
    running = R.verdict(flat(-2600.0).query("step < 1000000"), cell, check, 264)
    assert running["status"] == "running" and running["decided"] is None
    # the whole curve: a faithful pair passes; one that does nothing for the whole budget fails from 300k on
    pub = returns_five()
    rule = ladder.rule_of(cell)
    a, p = C.allowance(pub, 1_000_000, 2, rule)
    assert p <= 0.05 and a < 7
    good = pd.concat([curve(lambda s: -700.0 if s >= 300_000 else -2700.0, k, 1_000_000) for k in (0, 1)])
    v = C.whole_curve_verdict(good, pub, 1_000_000, (0, 1), rule)
    assert v["status"] == "pass" and v["first_success_status"] == "n/a"
    assert C.first_success_text(v) == "n/a: the metric is a return (no success threshold)"
    idle = C.whole_curve_verdict(flat(-2700.0), pub, 1_000_000, (0, 1), rule)
    assert idle["status"] == "fail" and [lo for lo, side in idle["out"]] == list(range(300_000, 1_000_000, 100_000))
    # the Normal model reaches beyond the published range; the Beta would clip a return into [0, 1]
    draws = C.window_model(np.array([-900.0, -700.0, -2200.0, -500.0, 100.0]), np.random.default_rng(0), 10_000,
                           bounded=False)
    assert draws.min() < -2200 and draws.max() > 100 and draws.mean() == pytest.approx(-840, abs=30)
    # the tables round a return to a whole number and write its range with "to"
    ours = good.assign(suite="returns", env="kitchen", algo="oracle", metric="deployed_return")
    t = R.ladder_table(ladder, ours, published=pub.assign(source="src", env="kitchen", algo="oracle",
                                                            metric="deployed_return"))
    assert t["metric"].tolist() == ["deployed_return"] and t["status"].tolist() == ["pass"]
    md = R.table_markdown(t)
    assert "| -840 (-2200 to 100) | -700 (-700, -700) | pass | pass: 0 of 10 windows out" in md
    assert md.rstrip().endswith("| n/a: the metric is a return (no success threshold) |")
