"""The ``harness`` command line.

    harness list                                  algorithms, envs and suites
    harness run suite=NAME [key=value ...]        run a suite (or algo=... env=... ad hoc)
    harness tune algo=medal env=NAME trials=N     an Optuna study over the algorithm's hyperparameters
    harness tune algo=medal env=NAME --best       the best parameters as a YAML override
    harness data fetch [--dest DIR] [--base-url URL]
    harness data scripted [env=NAME] [out=DIR]    scripted demonstrations (demo_source=scripted)
    harness bench env [envs=a,b] [steps=N]
    harness bench train algo=medal env=sawyer_door members=E
    harness bench update algo=medal env=sawyer_door [update=default]   one SAC update against its matmul ceiling
    harness bench matmul [members=E] [repeats=5]   member-batched products of the SAC update
    harness bench app [runs=100] [evals=300] [repeats=3] [results=DIR]   dashboard page-load time
    harness report [suite=NAME] [results=DIR] [out=DIR] [doc=FILE]
    harness ship suite=NAME results=DIR [to=results] [force=true]   copy a suite's evaluation tables (no checkpoints)

Bad input gets one line on stderr naming the problem and exit code 2; nothing is written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from harness import command_keys as keys
from harness import data as data_mod
from harness.words import ConfigError, UsageError, boolean, optional_integer, parse_words


def parse_overrides(items: list[str], allowed: set[str] | None = None) -> dict[str, str]:
    """``key=value`` words into a dict (values stay strings; callers validate)."""
    return parse_words(items, allowed)[0]


def _csv(v: str | None) -> list[str] | None:
    return [x for x in v.split(",") if x] if v else None


def cmd_list(args) -> int:
    from harness.catalogue import algorithm_summaries
    from harness.envs import ENVS, UNAVAILABLE_ENVS
    from harness.suites import list_suites, load_suite

    print("algorithms:")
    for name, doc in algorithm_summaries().items():
        print(f"  {name:<14} {doc}")
    print("envs:")
    for name, info in ENVS.items():
        why = info.unavailable()  # an optional simulator not installed
        print(f"  {name:<22} {why}" if why else f"  {name}")
    for name, why in UNAVAILABLE_ENVS.items():
        print(f"  {name:<22} {why}")
    print("suites:")
    for name in list_suites():
        print(f"  {name:<14} {load_suite(name)[1].get('description', '')}")
    return 0


def cmd_data(args) -> int:
    if args.data_cmd == "fetch":
        dest = Path(args.dest) if args.dest else None
        out = data_mod.fetch(dest=dest, base_url=args.base_url)
        print(f"EARL demonstrations written to {out}")
        return 0
    if args.data_cmd == "scripted":
        from harness.envs import ENVS
        from harness.envs.experts import generate_demos

        ov = parse_overrides(args.overrides, {"env", *keys.SCRIPTED})
        envs = _csv(ov.get("envs") or ov.get("env")) or [e for e, info in ENVS.items() if info.experts]
        for e in envs:
            if e not in ENVS:
                raise UsageError(f"unknown env {e!r}; known envs: {', '.join(ENVS)}")
            if not ENVS[e].experts:
                raise UsageError(f"env {e!r} has no scripted experts (its EnvInfo.experts): no scripted demos")
        out = Path(ov["out"]) if "out" in ov else data_mod.cache_dir()
        seed = optional_integer("seed", ov.get("seed"), 0)
        from harness.envs.base import resolve

        writers = dict.fromkeys(ENVS[e].offline_assets for e in envs if ENVS[e].offline_assets)
        for writer in writers:
            resolve(writer)(out)  # the env's model files (checked against EARL's), before the env is built
        if writers and data_mod.explicit_data_dir() is None:
            data_mod.set_data_dir(out)  # the experts' envs load the model files just written
        for e in envs:
            for direction, n in zip(data_mod.DIRECTIONS, ENVS[e].scripted_demos):
                arrays = generate_demos(e, direction, n, seed)
                path = out / "demos" / e / f"{direction}.npz"
                data_mod.save_demos(path, arrays, source="scripted")
                print(f"{path}: {n} scripted trajectories, {len(arrays['actions'])} transitions")
        return 0
    raise UsageError("usage: harness data {fetch,scripted}")


def cmd_bench(args) -> int:
    if args.what == "env":
        from harness.bench.env import bench_env
        from harness.envs import check_env

        ov = parse_overrides(args.overrides, {"env", *keys.BENCH["env"]})
        envs = _csv(ov.get("envs") or ov.get("env"))
        for e in envs or []:
            check_env(e)  # unknown, never released or its simulator not installed: one line
        steps = optional_integer("steps", ov.get("steps"), 0, 1) if "steps" in ov else None
        bench_env(envs, steps, optional_integer("repeats", ov.get("repeats"), 5, 1))
        return 0
    if args.what == "train":
        from harness.bench.train import bench_train_cli

        return bench_train_cli(parse_overrides(args.overrides))
    if args.what == "update":
        from harness.bench.update import bench_update_cli

        return bench_update_cli(parse_overrides(args.overrides))
    if args.what == "matmul":
        from harness.bench.env import bench_matmul

        ov = parse_overrides(args.overrides, set(keys.BENCH["matmul"]))
        bench_matmul(optional_integer("members", ov.get("members"), 2, 1),
                     optional_integer("repeats", ov.get("repeats"), 5, 1))
        return 0
    if args.what == "app":
        from harness.bench.app import bench_app_cli

        return bench_app_cli(parse_overrides(args.overrides, set(keys.BENCH["app"])))
    raise UsageError(f"unknown benchmark {args.what!r}; known: env, train, update, matmul, app")


def cmd_run(args) -> int:
    from harness.runner import run_cli

    return run_cli(args.overrides, dry_run=args.dry_run)


def cmd_report(args) -> int:
    from harness.report import report_cli

    return report_cli(args.overrides)


def cmd_ship(args) -> int:
    from harness.results import ship

    ov = parse_overrides(args.overrides, set(keys.SHIP))
    if "suite" not in ov or "results" not in ov:
        raise UsageError("usage: harness ship suite=NAME results=DIR [to=results] [force=true]")
    force = boolean("force", ov.get("force", "false"))
    written, kept = ship(ov["results"], ov["suite"], ov.get("to", "results"), force=force)
    runs = len({p.parent for p in written})
    print(f"{len(written)} files of {runs} run(s) copied to {Path(ov.get('to', 'results')) / ov['suite']}")
    for run in kept:
        print(f"kept the shipped table of {run}; force=true replaces it")
    dest = Path(ov.get("to", "results")) / ov["suite"]
    ignored = git_ignored(dest) if written else None
    if ignored is not None:
        print(f"harness: note: {dest} is ignored by git, so the shipped tables will not be committed; un-ignore it "
              f"(a line '!/{ignored}/' in .gitignore) to ship them with the code", file=sys.stderr)
    return 0


def git_ignored(path: Path) -> str | None:
    """``path`` relative to the root of the git work tree it lies in, if that work tree ignores it; None when it does
    not, outside a work tree, or without git."""
    import subprocess

    def git(*words: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *words], cwd=path, capture_output=True, text=True, timeout=10)

    try:
        if git("check-ignore", "-q", ".").returncode != 0:
            return None
        root = git("rev-parse", "--show-toplevel").stdout.strip()
        return path.resolve().relative_to(Path(root).resolve()).as_posix()
    except (OSError, ValueError, subprocess.SubprocessError):
        return None


def cmd_status(args) -> int:
    from harness.run_status import run_status, status_text

    ov = parse_overrides(args.overrides, set(keys.STATUS))
    results = Path(ov.get("results", "results"))
    if not results.is_dir():
        raise UsageError(f"results directory not found: {results}; pass results=DIR (where `harness run` wrote)")
    df = run_status(results)
    if "suite" in ov:
        df = df[df["suite"] == ov["suite"]]
    print(status_text(df))
    return 0


def cmd_tune(args) -> int:
    from harness.tune.command import tune_cli

    return tune_cli(args.overrides, best=args.best)


def keys_help(table: dict[str, Any], algorithm_settings: bool = True) -> str:
    """The epilog of ``run``/``tune --help``: every key=value word with its default and meaning (a table of
    :class:`harness.request.Key`, or of (default, meaning) pairs), then every algorithm setting (the shared SAC ones
    once, then each algorithm's own)."""
    lines = ["keys (key=value, in any order, flags anywhere):"]
    for k, v in table.items():
        default, meaning = (v.default_text, v.help) if hasattr(v, "default_text") else v
        lines.append(f"  {k:<18} {meaning} [default: {default}]")
    if algorithm_settings:
        from algorithms.common import SACAlgoConfig
        from harness.registry import ALGORITHMS

        lines += ["", "algorithm settings (<algo>.<key>=value, or all.<key>=value for every selected algorithm that "
                      "has the key); defaults shown are the dataclass defaults, per-env values in "
                      "suites/algorithms/<algo>.yaml:", "  SAC, shared by every SAC-based algorithm:"]
        shared = {k for k, _, _ in SACAlgoConfig.describe()}
        lines += [f"    {k:<24} {h} [default: {d}]" for k, d, h in SACAlgoConfig.describe()]
        for name, cls in ALGORITHMS.items():
            own = [(k, d, h) for k, d, h in cls.Config.describe()
                   if k not in shared or d != getattr(SACAlgoConfig(), k, object())]
            if own:
                lines.append(f"  {name}:")
                lines += [f"    {k:<24} {h} [default: {d}]" for k, d, h in own]
    return "\n".join(lines)


class Parser(argparse.ArgumentParser):
    """argparse with the harness's error format: one line on stderr, exit code 2. ``epilog`` may be a function, called
    when the help is printed (the run and tune epilogs list every algorithm's settings, which imports torch)."""

    def format_help(self) -> str:
        if callable(self.epilog):
            self.epilog = self.epilog()
        return super().format_help()

    def error(self, message: str):
        print(f"harness: error: {message} (see `{self.prog} --help`)", file=sys.stderr)
        sys.exit(2)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="harness", description="EARL benchmark harness for reset-free RL",
               formatter_class=argparse.RawDescriptionHelpFormatter, epilog=(
                   "first steps:\n"
                   "  harness list                                    algorithms, envs, suites\n"
                   "  harness run suite=smoke                         every algorithm x env, tiny budgets (minutes)\n"
                   "  harness run algo=medal env=sawyer_door steps=50k --dry-run   the plan and its time\n"
                   "  harness status results=results                  every run: step, steps/s, ETA\n"
                   "  harness report results=results                  curves and Table 1 from the results\n"
                   "  streamlit run app.py                            the dashboard\n"
                   "  harness COMMAND --help                          a command's keys"))
    p.add_argument("--data-dir", help="EARL data directory (default: HARNESS_DATA_DIR, cache, ../shared/earl)")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=Parser)
    sub.add_parser("list", help="list algorithms, envs and suites").set_defaults(fn=cmd_list)

    def run_help() -> str:
        from harness.request import RUN_KEYS

        return keys_help(RUN_KEYS)

    def tune_help() -> str:
        from harness.tune.setup import TUNE_KEY_HELP

        return keys_help(TUNE_KEY_HELP)

    raw = argparse.RawDescriptionHelpFormatter
    r = sub.add_parser("run", help="run a suite or an ad-hoc set of runs (key=value overrides)",
                       epilog=run_help, formatter_class=raw)
    r.add_argument("overrides", nargs="*")
    r.add_argument("--dry-run", action="store_true", help="print the plan and exit")
    r.set_defaults(fn=cmd_run)

    t = sub.add_parser("tune", help="tune an algorithm's hyperparameters with Optuna (key=value overrides)",
                       epilog=tune_help, formatter_class=raw)
    t.add_argument("overrides", nargs="*")
    t.add_argument("--best", action="store_true", help="print the study's best parameters as a YAML override")
    t.set_defaults(fn=cmd_tune)

    rp = sub.add_parser("report", help="curves (PNG/PDF) and Table 1 (Markdown/LaTeX/CSV) from results",
                        epilog=keys_help(keys.REPORT, False), formatter_class=raw)
    rp.add_argument("overrides", nargs="*")
    rp.set_defaults(fn=cmd_report)

    sh = sub.add_parser("ship", help="copy a suite's evaluation tables (evals.parquet, run.yaml, status.json) "
                                     "to another results directory, without checkpoints",
                        epilog=keys_help(keys.SHIP, False), formatter_class=raw)
    sh.add_argument("overrides", nargs="*")
    sh.set_defaults(fn=cmd_ship)

    stat = sub.add_parser("status", help="every run under a results directory: state, step, steps/s, ETA, last "
                                         "success", epilog=keys_help(keys.STATUS, False), formatter_class=raw)
    stat.add_argument("overrides", nargs="*")
    stat.set_defaults(fn=cmd_status)

    d = sub.add_parser("data", help="fetch or generate demonstrations")
    dsub = d.add_subparsers(dest="data_cmd", required=True)
    f = dsub.add_parser("fetch", help="download EARL's demonstrations into the cache")
    f.add_argument("--dest", help="target directory (default: the project cache)")
    f.add_argument("--base-url", default=data_mod.EARL_REPO_URL)
    s = dsub.add_parser("scripted", help="generate demonstrations with the scripted experts",
                        epilog=keys_help(keys.SCRIPTED, False), formatter_class=raw)
    s.add_argument("overrides", nargs="*")
    d.set_defaults(fn=cmd_data)

    b = sub.add_parser("bench", help="benchmarks: env and training throughput, network products, dashboard page-load "
                                      "time", formatter_class=raw,
                       epilog="\n\n".join(f"harness bench {what}: " + keys_help(table, False)
                                            for what, table in keys.BENCH.items()))
    b.add_argument("what", choices=["env", "train", "update", "matmul", "app"])
    b.add_argument("overrides", nargs="*")
    b.set_defaults(fn=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    import yaml

    from harness.backends import Interrupted
    from harness.envs import UnknownEnvError

    parser = build_parser()
    words = sys.argv[1:] if argv is None else argv
    if not words or words[0] == "help":  # a first look (`harness`, `harness help`): the commands, not an error
        parser.print_help()
        return 0
    # flags may stand anywhere among the key=value words: argparse stops filling ``overrides`` at the first flag and
    # hands back the words after it, which are key=value words too
    args, extra = parser.parse_known_args(argv)
    if extra:
        if not hasattr(args, "overrides"):
            parser.parse_args(argv)  # the usual argparse error for what is really unknown
        flags = [w for w in extra if w.startswith("-")]
        if flags:  # name only the unknown flags, not the key=value words that followed them
            top = [f for f in flags if f.split("=", 1)[0] == "--data-dir"]
            command = " ".join(["harness", args.cmd, *([args.data_cmd] if getattr(args, "data_cmd", None) else [])])
            why = (f"{top[0].split('=', 1)[0]} goes before the command (harness --data-dir DIR {args.cmd} ...)" if top
                   else f"unknown flag(s) {' '.join(flags)} (see `{command} --help`)")
            print(f"harness: error: {why}", file=sys.stderr)
            return 2
        args.overrides = [*args.overrides, *extra]
    previous = data_mod._explicit_default
    data_mod.set_data_dir(args.data_dir)
    try:
        return args.fn(args)
    except (ConfigError, data_mod.DataNotFoundError, UnknownEnvError, yaml.YAMLError) as e:
        msg = " ".join(str(e).split())
        print(f"harness: error: {msg}", file=sys.stderr)
        return 2
    except Interrupted as e:
        print(f"harness: interrupted: {e.runs} run group(s) stopped at their last checkpoint; run the same command "
              "again to resume them", file=sys.stderr)
        return 130
    except KeyboardInterrupt:
        print("harness: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (harness list | head): nothing more to say
        sys.stderr.close()
        return 0
    finally:
        data_mod.set_data_dir(previous)  # main() called in-process (tests, notebooks) leaves no global behind


if __name__ == "__main__":
    sys.exit(main())
