"""``harness report [suite=NAME] [results=DIR] [out=DIR] [step=last|matched|N] [smooth=K] [published=SRC,...] [doc=FILE]``

Writes to ``out`` (default ``<results>/report/<suite or all>``):

- ``curves.png`` / ``curves.pdf``: deployed success vs environment steps, one subplot per env,
  methods overlaid (mean over seeds on the common grid, standard-error band; see
  ``harness.analysis``), published curves of the same methods dashed (``published=``: sources among
  ``risc_paper``, ``earl_benchmark``, or ``none``; default ``risc_paper``), clipped to the step
  range of our runs in that env;
- ``table1.md`` / ``table1.tex`` / ``table1.csv``: our final performance, mean (SE) over seeds,
  beside the MEDAL paper's Table 1 and the difference, best per env in bold
  (``step=last``: each run's last evaluation, the default; ``matched``: the largest step every run
  in the env reached; ``N``: the last evaluation at or before step N);
- ``table1_evidence.md``: per Table-1 cell, whether the results verify it, at which budget and with which
  verdicts (final window, whole curve, first success; :mod:`harness.evidence`), from every ladder suite's rows;
- ``aggregates.csv``: IQM and mean across envs with 95% stratified-bootstrap CIs;
- for a suite with ``cells`` (``suites/reproduction.yaml``): ``reproduction.png``/``.pdf`` and
  ``reproduction.md``/``.csv``, the verdict of every check (``harness.reproduction``); ``doc=FILE.md``
  also rewrites that table between ``<!-- table:SUITE -->`` markers in FILE.md and draws the figure
  beside it as ``SUITE.png``.

Bad input raises :class:`harness.suites.ConfigError` with one line.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pandas as pd

from harness import analysis as A
from harness.command_keys import CURVE_METRICS, PUBLISHED_SOURCES
from harness.command_keys import REPORT as REPORT_KEYS
from harness.evidence import evidence_markdown, table1_evidence
from harness.labels import algo_label, env_label, method_colors, order_algos, order_envs
from harness.stats import aggregate_scores, no_shared_env
from harness.suites import ConfigError, list_suites, load_suite
from harness.tables import table1, table1_csv, table1_latex, table1_markdown
from harness.words import integer as parse_int
from harness.words import name_of, parse_words

Y_LABELS = {"deployed_success": "Deployed success", "deployed_return": "Deployed return",
            "continuing_reward": "Cumulative training reward", "interventions": "Interventions"}
KEYS = set(REPORT_KEYS)


def parse(overrides: list[str]) -> dict[str, str]:
    return parse_words(overrides, KEYS)[0]


def algo_colors(algos) -> dict[str, str]:
    """The fixed colour of each method (:data:`harness.labels.METHOD_COLORS`, the dashboard's too)."""
    return method_colors(algos)


def plot_curves(curves: pd.DataFrame, published: pd.DataFrame | None, metric: str = "deployed_success"):
    """A matplotlib Figure (no pyplot state): one subplot per env, methods overlaid with SE band,
    published curves dashed."""
    import matplotlib
    from matplotlib.figure import Figure

    envs = order_envs(curves["env"])
    algos = order_algos(curves["algo"])
    colors = algo_colors(list(algos) + (list(published["algo"].unique()) if published is not None else []))
    ncols = min(3, max(len(envs), 1))
    nrows = math.ceil(len(envs) / ncols) if envs else 1
    with matplotlib.rc_context({"font.size": 9, "axes.titlesize": 10, "pdf.fonttype": 42, "ps.fonttype": 42,
                                "axes.spines.top": False, "axes.spines.right": False}):
        fig = Figure(figsize=(3.4 * ncols, 2.6 * nrows + 0.6), layout="constrained")
        axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
        handles: dict[str, object] = {}
        dashes = {src: d for src, d in zip(PUBLISHED_SOURCES, [(4, 2), (1, 1.5)])}
        for ax, env in zip(axes, envs):
            c = curves[curves["env"] == env]
            xmax = float(c["step"].max()) if len(c) else 0.0
            scale, unit = (1e6, "M") if xmax >= 1e6 else (1e3, "k")
            for algo in algos:
                g = c[c["algo"] == algo].sort_values("step")
                if g.empty:
                    continue
                x = g["step"].to_numpy() / scale
                (h,) = ax.plot(x, g["mean"], color=colors[algo], lw=1.6, label=algo_label(algo))
                ax.fill_between(x, g["mean"] - g["se"], g["mean"] + g["se"], color=colors[algo], alpha=0.2, lw=0)
                handles.setdefault(algo_label(algo), h)
            if published is not None and len(published):
                p = published[(published["env"] == env) & published["algo"].isin(algos) & (published["step"] <= xmax)]
                for (src, algo), g in p.groupby(["source", "algo"]):
                    g = g.sort_values("step")
                    label = f"{algo_label(algo)} ({src})"
                    (h,) = ax.plot(g["step"] / scale, g["mean"], color=colors[algo], lw=1.2,
                                   dashes=dashes.get(src, (2, 2)), label=label)
                    handles.setdefault(label, h)
            ax.set_title(env_label(env))
            ax.set_xlabel(f"Environment steps ({unit})")
            ax.grid(alpha=0.25, lw=0.5)
            if metric == "deployed_success":
                ax.set_ylim(-0.03, 1.03)
        for ax in axes[: len(envs)][::ncols]:
            ax.set_ylabel(Y_LABELS.get(metric, metric))
        for ax in axes[len(envs):]:
            ax.set_visible(False)
        if handles:
            fig.legend(list(handles.values()), list(handles.keys()), loc="outside lower center",
                       ncols=min(len(handles), 4), frameon=False)
    return fig


def is_cells_suite(suite: str | None) -> bool:
    """Whether ``suite`` names a suite file (in suites/ or a path) with ``cells``; results may carry suite names that
    have no file (tuning studies, fixtures), which are not."""
    from harness.suites import SUITES_DIR

    if not suite or not ((SUITES_DIR / f"{suite}.yaml").is_file() or Path(suite).is_file()):
        return False
    return "cells" in load_suite(suite)[1]


def _published(warn: bool = True) -> pd.DataFrame | None:
    """The published curves, read once per report; where they cannot be read, ours alone, and with ``warn`` (the
    report draws or checks against them) one warning."""
    from harness.data import DataNotFoundError
    from harness.results import load_published

    try:
        return load_published()
    except (DataNotFoundError, OSError) as e:
        if warn:
            print(f"harness report: warning: published curves not drawn: {' '.join(str(e).split())}", file=sys.stderr)
        return None


def _save_figure(fig, stem: Path, png_dpi: int) -> list[Path]:
    """``stem``.png and ``stem``.pdf."""
    paths = [stem.with_suffix(".png"), stem.with_suffix(".pdf")]
    fig.savefig(paths[0], dpi=png_dpi, bbox_inches="tight")
    fig.savefig(paths[1], bbox_inches="tight")
    return paths


def write_reproduction(suite: str, df: pd.DataFrame, out: Path, doc: str | None = None,
                       published: pd.DataFrame | None = None) -> list[Path]:
    """For a suite with cells: ``reproduction.png``/``.pdf`` (one panel per cell, our seeds and the published ones,
    windows shaded, verdicts) and ``reproduction.md``/``.csv`` (the table of checks; the Markdown adds what the runs
    cost, :func:`harness.reproduction.ladder_cost`, and the commits that produced the rows,
    :func:`harness.reproduction.ladder_commits`); with ``doc``, those tables also replace the
    ``<!-- table:SUITE -->`` block of the Markdown file ``doc``."""
    from harness import ladder_provenance as P
    from harness import reproduction as R
    from harness.ladder_figure import plot_ladder

    ladder = R.load_ladder(suite)
    fig = plot_ladder(ladder, df, published)
    written = _save_figure(fig, out / "reproduction", 150)
    t = R.ladder_table(ladder, df, published=published)
    tables = (R.table_markdown(t) + "\nWhat the runs cost (the shipped rows):\n\n" + P.cost_markdown(P.ladder_cost(ladder, df))
              + "\nThe commits that produced the rows (`git_sha`), with the steps each one evaluated:\n\n"
              + P.commits_markdown(P.ladder_commits(ladder, df)))
    (out / "reproduction.md").write_text(tables)
    if doc:  # the tables into the document, the figure beside it as <suite>.png
        path = Path(doc)
        path.write_text(R.replace_doc_table(path.read_text(), suite, tables))
        fig.savefig(path.parent / f"{suite}.png", dpi=110, bbox_inches="tight")
        written += [path, path.parent / f"{suite}.png"]
    t.drop(columns=["ours_per_seed", "band"]).assign(
        ours_per_seed=[" ".join(f"{x:.3f}" for x in v) for v in t["ours_per_seed"]]).to_csv(out / "reproduction.csv",
                                                                                       index=False)
    return written + [out / "reproduction.md", out / "reproduction.csv"]


def _check_doc(ov: dict, suite: str | None) -> None:
    """doc=: a reproduction suite's table block must exist in that file (one line otherwise)."""
    if "doc" not in ov:
        return
    from harness.reproduction import replace_doc_table

    if not is_cells_suite(suite):
        raise ConfigError("doc= rewrites a reproduction suite's table: give a suite with cells")
    if not Path(ov["doc"]).is_file():
        raise ConfigError(f"doc= file not found: {ov['doc']}")
    replace_doc_table(Path(ov["doc"]).read_text(), suite, "")


def report_cli(overrides: list[str]) -> int:
    from harness.results import COLUMNS, META_COLUMNS, RETURN_ENVS, load, runs_holding

    ov = parse(overrides)
    for key in ("results", "out", "suite", "doc"):
        if key in ov and not str(ov[key]).strip():
            raise ConfigError(f"{key}= is empty: give a value (or leave {key} out for its default)")
    results = Path(ov.get("results", "results"))
    suite = ov.get("suite")
    if suite:  # a suite of suites/ in any case
        suite = name_of(suite, list_suites(), parts=False)
    if not results.exists() and not is_cells_suite(suite):  # a suite of checks is reported before its runs too
        raise ConfigError(f"results directory not found: {results}; run `harness run suite=...` first or pass results=DIR")
    out = Path(ov["out"]) if "out" in ov else results / "report" / (suite or "all")
    # deployed_return where every env selected publishes returns (below); success, return: the deployed ones
    metric = name_of(ov.get("metric", "deployed_success"), CURVE_METRICS)
    if metric not in CURVE_METRICS:
        raise ConfigError(f"unknown metric {metric!r} for curves; known: {', '.join(CURVE_METRICS)}")
    step_opt = ov.get("step", "last")
    step: int | str | None
    if step_opt == "last":
        step = None
    elif step_opt == "matched":
        step = "matched"
    else:
        step = parse_int("step", step_opt, 0)
    window = parse_int("smooth", ov.get("smooth", "1"), 1)
    srcs = [s for s in ov.get("published", "risc_paper").split(",") if s and s != "none"]
    for s in srcs:
        if s not in PUBLISHED_SOURCES:
            raise ConfigError(f"unknown published source {s!r}; known: {', '.join(PUBLISHED_SOURCES)}, none")

    warnings: list[str] = []
    df = load(results, warn=warnings.append) if results.exists() else pd.DataFrame(columns=COLUMNS + META_COLUMNS)
    for w in warnings:
        print(f"harness report: warning: {w}", file=sys.stderr)
    if suite and is_cells_suite(suite) and (df.empty or not (df["suite"] == suite).any()):
        # a reproduction suite before its runs: its checks, every one "not started" (what will be judged, and how)
        _check_doc(ov, suite)
        out.mkdir(parents=True, exist_ok=True)
        print(f"harness report: note: no results for suite {suite!r} under {results} yet: its checks are shown, "
              "not started", file=sys.stderr)
        for p in write_reproduction(suite, pd.DataFrame(columns=COLUMNS + META_COLUMNS), out, ov.get("doc"),
                                    _published()):
            print(p)
        return 0
    if df.empty:
        raise ConfigError(f"no results (evals.parquet) under {results}; run `harness run suite=...` first")
    everything = df  # Table 1's evidence reads every ladder suite's rows, whatever suite= selects
    if not (suite or "").startswith("tune_"):
        df = df[~A.is_tuning(df)]  # harness tune trials: only when their suite is named
        if df.empty:
            raise ConfigError(f"only `harness tune` trials under {results}; name one with suite=tune_<study>")
    if suite:
        known = sorted(df["suite"].dropna().astype(str).unique())
        df = df[df["suite"] == suite]
        if df.empty:
            raise ConfigError(f"no results for suite {suite!r} under {results}; suites with results: {', '.join(known)}")
    if "metric" not in ov and df["env"].isin(RETURN_ENVS).all():
        metric = "deployed_return"  # kitchen and minitaur: the published curves are returns
    if "published" not in ov and (df["env"] == "kitchen").any():
        srcs.append("earl_benchmark")  # kitchen's published curves are EARL's own
    if not (df["metric"] == "deployed_success").any():
        raise ConfigError(f"no deployed_success rows under {results}" + (f" for suite {suite!r}" if suite else ""))
    if isinstance(step, int) and step > (furthest := int(df["step"].max())):
        raise ConfigError(f"step={step:,} is past every run (the furthest evaluated step is {furthest:,}): Table 1 "
                          "would be empty; give step=last, matched or a step the runs reached")

    _check_doc(ov, suite)  # before anything is written

    cells_df = df  # the reproduction verdicts read cells by their own names
    df = A.separate_suites(df)  # a method's runs from several suites are never pooled (MEDAL · smoke, ...)
    curves = A.learning_curves(df, metric, window=window)
    published = _published(warn=bool(srcs) or is_cells_suite(suite))  # else the evidence: final windows only
    pub_curves = None
    if srcs and published is not None:
        pub_curves = A.learning_curves(A.same_pairs(A.select(published, metric, source=srcs), curves), metric,
                                       window=window)

    out.mkdir(parents=True, exist_ok=True)
    written = _save_figure(plot_curves(curves, pub_curves, metric), out / "curves", 200)

    t = table1(df, step=step)
    for name, text in (("table1.md", table1_markdown(t)), ("table1.tex", table1_latex(t)),
                       ("table1.csv", table1_csv(t))):
        (out / name).write_text(text)
        written.append(out / name)

    (out / "table1_evidence.md").write_text(
        "Which Table-1 cells the results verify (reproduction cells, docs/reproduction.md):\n\n"
        + evidence_markdown(table1_evidence(everything, published, runs_holding(results))))
    written.append(out / "table1_evidence.md")

    scores = A.final_scores(df, step=step)
    agg = aggregate_scores(scores)
    if agg.empty and len(scores):
        print("harness report: note: aggregates.csv has no rows: the aggregates compare methods over the envs they all "
              f"share, and no env has results of every method ({no_shared_env(scores, scores['algo'].unique())})",
              file=sys.stderr)
    agg.to_csv(out / "aggregates.csv", index=False)
    written.append(out / "aggregates.csv")
    if is_cells_suite(suite):
        written += write_reproduction(suite, cells_df, out, ov.get("doc"), published)
    for p in written:
        print(p)
    return 0
