"""``harness report``: files written, numbers equal a direct pandas computation, bad input = ConfigError."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from harness.report import report_cli
from harness.results import load
from harness.suites import ConfigError
from tests import fixtures_results as F


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return F.write_fixture(tmp_path_factory.mktemp("results"), corrupt=True)  # with a `harness tune` trial run


@pytest.fixture(scope="module")
def report(results, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert report_cli([f"results={results}", f"out={out}", "suite=fixture"]) == 0
    return out


def test_files_written(report):
    for name in ("curves.png", "curves.pdf", "table1.md", "table1.tex", "table1.csv", "aggregates.csv"):
        p = report / name
        assert p.exists() and p.stat().st_size > 100, name
    assert (report / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (report / "curves.pdf").read_bytes()[:5] == b"%PDF-"


def test_table_numbers_equal_pandas(results, report):
    df = load(results, warn=lambda m: None)
    d = df[(df["metric"] == "deployed_success") & df["study"].isna()]  # tuning trials are left out
    last = d[d["step"] == d.groupby(["env", "algo", "seed"])["step"].transform("max")]
    direct = last.groupby(["env", "algo"])["value"].agg(["mean", "sem", "size"])
    t = pd.read_csv(report / "table1.csv")
    ours = t.dropna(subset=["ours_mean"]).set_index(["env", "algo"])
    assert len(ours) == len(direct) == len(F.ENVS) * len(F.ALGOS)
    for key, row in direct.iterrows():
        assert ours.loc[key, "ours_mean"] == pytest.approx(row["mean"])
        assert ours.loc[key, "ours_se"] == pytest.approx(row["sem"])
        assert ours.loc[key, "n"] == row["size"]
        if not np.isnan(ours.loc[key, "paper_mean"]):
            assert ours.loc[key, "diff"] == pytest.approx(row["mean"] - ours.loc[key, "paper_mean"])
    md = (report / "table1.md").read_text()
    mean, se = F.expected_final("sawyer_door", "medal")
    assert f"**{mean:.2f} ({se:.2f})**" in md
    assert r"\textbf{" in (report / "table1.tex").read_text()
    agg = pd.read_csv(report / "aggregates.csv").set_index("algo")
    assert agg.loc["medal", "mean"] == pytest.approx(direct.xs("medal", level="algo")["mean"].mean())


def test_default_out_and_matched(results):
    assert report_cli([f"results={results}", "step=matched", "published=none", "smooth=2"]) == 0
    assert (results / "report" / "all" / "table1.md").exists()


@pytest.mark.parametrize("args, needle", [
    (["bogus=1"], "unknown key 'bogus'"),
    (["noequals"], "expected key=value"),
    (["results=/nonexistent/dir"], "results directory not found"),
    (["suite=nope"], "no results for suite 'nope'"),
    (["step=abc"], "step must be an integer"),
    (["published=arxiv"], "unknown published source"),
    (["metric=foo"], "unknown metric"),
])
def test_bad_input_one_line(results, args, needle):
    if not any(a.startswith("results=") for a in args):
        args.append(f"results={results}")
    with pytest.raises(ConfigError) as e:
        report_cli(args)
    assert needle in str(e.value) and "\n" not in str(e.value)


def test_tuning_suite_on_request(results, tmp_path):
    assert report_cli([f"results={results}", f"suite=tune_{F.TUNE_STUDY}", f"out={tmp_path}"]) == 0
    t = pd.read_csv(tmp_path / "table1.csv").dropna(subset=["ours_mean"])
    assert list(t["algo"]) == ["medal"] and t["ours_mean"].iloc[0] == pytest.approx(0.99)


def test_empty_results_dir(tmp_path):
    with pytest.raises(ConfigError, match="no results"):
        report_cli([f"results={tmp_path}"])


def test_without_the_published_curves_one_warning_and_ours_alone(results, tmp_path, monkeypatch, capsys):
    """A data directory without EARL's reference curves: the report still writes every file, and says once why the
    published curves are missing (they were read once for the curves, the evidence and the reproduction checks)."""
    monkeypatch.setenv("HARNESS_DATA_DIR", str(tmp_path / "empty"))
    assert report_cli([f"results={results}", f"out={tmp_path / 'out'}", "suite=fixture"]) == 0
    err = capsys.readouterr().err
    assert err.count("published curves not drawn") == 1, err
    assert (tmp_path / "out" / "curves.png").stat().st_size > 100
    assert (tmp_path / "out" / "table1_evidence.md").exists()
    assert report_cli([f"results={results}", f"out={tmp_path / 'out2'}", "suite=fixture", "published=none"]) == 0
    assert "published curves not drawn" not in capsys.readouterr().err  # none asked for: nothing to warn about
