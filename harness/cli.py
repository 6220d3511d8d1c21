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
import re
import sys
from typing import Any

from harness import command_keys as keys
from harness import data as data_mod
from harness.commands import (
    LIST_PARTS,
    cmd_bench,
    cmd_data,
    cmd_list,
    cmd_report,
    cmd_run,
    cmd_ship,
    cmd_status,
    cmd_tune,
)
from harness.words import ConfigError

#: the flags argparse itself reads; any other ``--key value`` / ``--key=value`` is the word ``key=value``
FLAGS = ("--dry-run", "--best", "--data-dir", "--dest", "--base-url", "--help", "-h", "--version")


BENCH_HELP = {"env": "raw env steps/s (MuJoCo, Meta-World, pybullet)", "train": "training steps/s of one group, with "
              "the time split", "update": "one SAC update against its matmul ceiling", "matmul": "the update's "
              "member-batched products: torch.bmm vs ours", "app": "dashboard page-load time"}
#: commands whose next word names what to do (``harness bench train``, ``harness data fetch``)
GROUPS = ("bench", "data")


def flag_words(argv: list[str]) -> list[str]:
    """The command line as people type it, in the harness's words: after the command (and a ``bench``/``data``
    command's own word), ``--steps 3000`` and ``--steps=3000`` become ``steps=3000`` (the key's dashes are read as
    underscores later; a value may be a negative number, never another flag or a ``key=value`` word), up to a bare
    ``--``; and ``--data-dir DIR`` may stand anywhere (it moves before the command)."""
    front, out, i, commands = [], [], 0, []  # commands: the command's words seen so far
    while i < len(argv):
        w = argv[i]
        name, has_value = w.split("=", 1)[0], "=" in w
        nxt = argv[i + 1] if i + 1 < len(argv) else None
        takes_next = not has_value and nxt is not None and "=" not in nxt and (
            not nxt.startswith("-") or re.fullmatch(r"-[0-9.]+(e[+-]?[0-9]+)?", nxt) is not None)
        command_done = len(commands) >= (2 if commands[:1] and commands[0] in GROUPS else 1)
        if w == "--":
            out += argv[i:]
            break
        if name == "--data-dir":
            front += [w] if has_value or nxt is None else [w, nxt]
            i += 1 if has_value or nxt is None else 2
        elif command_done and name.startswith("--") and len(name) > 2 and name not in FLAGS and (
                has_value or takes_next):
            out.append(f"{name[2:]}={w.split('=', 1)[1] if has_value else nxt}")
            i += 1 if has_value else 2
        else:
            if not command_done and not w.startswith("-"):
                commands.append(w)
            out.append(w)
            i += 1
    return front + out


def keys_help(table: dict[str, Any], algorithm_settings: bool = True) -> str:
    """The epilog of ``run``/``tune --help``: every key=value word with its default and meaning (a table of
    :class:`harness.request.Key`, or of (default, meaning) pairs), then every algorithm setting (the shared SAC ones
    once, then each algorithm's own)."""
    lines = ["keys (key=value, in any order, flags anywhere):"]
    for k, v in table.items():
        default, meaning = (v.default_text, v.help) if hasattr(v, "default_text") else v
        lines.append(f"  {k:<18} {meaning} [default: {default}]")
    if algorithm_settings:
        lines += ["", settings_help()]
    return "\n".join(lines)


def settings_help() -> str:
    """Every algorithm setting with its meaning and default (the shared SAC ones once, then each algorithm's own).
    Reading them imports every algorithm and torch (seconds), so the text is kept in the state directory, keyed by
    the source of algorithms/ and the registry: the next ``--help`` answers at once."""
    import hashlib

    from harness.catalogue import ROOT, algorithm_summaries
    from harness.data import atomic_write_bytes, state_dir

    sources = sorted((ROOT / "algorithms").rglob("*.py")) + [ROOT / "harness" / "registry.py"]
    key = hashlib.sha256(b"".join(p.read_bytes() for p in sources)).hexdigest()[:16]
    cached = state_dir() / f"settings_help-{key}.txt"
    if cached.is_file():
        return cached.read_text()
    from algorithms.common import SACAlgoConfig
    from harness.registry import ALGORITHMS

    lines = ["algorithm settings (<algo>.<key>=value, or all.<key>=value for every selected algorithm that has the key);"
             " defaults shown are the dataclass defaults, per-env values in suites/algorithms/<algo>.yaml:",
             "  SAC, shared by every SAC-based algorithm:"]
    shared = {k for k, _, _ in SACAlgoConfig.describe()}
    lines += [f"    {k:<24} {h} [default: {d}]" for k, d, h in SACAlgoConfig.describe()]
    for name, cls in ALGORITHMS.items():
        own = [(k, d, h) for k, d, h in cls.Config.describe()
               if k not in shared or d != getattr(SACAlgoConfig(), k, object())]
        if own:
            lines.append(f"  {name}:")
            lines += [f"    {k:<24} {h} [default: {d}]" for k, d, h in own]
    text = "\n".join(lines)
    if tuple(ALGORITHMS) == tuple(algorithm_summaries()):  # the registry as its source says: no run-time addition
        try:
            for old in state_dir().glob("settings_help-*.txt"):
                old.unlink(missing_ok=True)
            atomic_write_bytes(cached, text.encode())
        except OSError:
            pass  # a read-only state directory: computed each time
    return text


class Parser(argparse.ArgumentParser):
    """argparse with the harness's error format: one line on stderr, exit code 2. ``epilog`` may be a function, called
    when the help is printed (the run and tune epilogs list every algorithm's settings, which imports torch)."""

    def format_help(self) -> str:
        if callable(self.epilog):
            self.epilog = self.epilog()
        return super().format_help()

    def error(self, message: str):
        import re

        from harness.words import did_you_mean

        bad = re.fullmatch(r"argument (\w+): invalid choice: '(.*)' \(choose from (.*)\)", message)
        if bad:  # argparse's own words (its dest names, quoting) said as the command's
            known = [c.strip(" '") for c in bad[3].split(",")]
            what = {"cmd": "command", "what": "benchmark", "data_cmd": "data command"}.get(bad[1], "choice")
            message = f"unknown {what} {bad[2]!r}{did_you_mean(bad[2], known)}; known: {', '.join(known)}"
        print(f"harness: error: {message} (see `{self.prog} --help`)", file=sys.stderr)
        sys.exit(2)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("earl-harness")
    except PackageNotFoundError:
        return "(not installed)"


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
    p.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    sub = p.add_subparsers(dest="cmd", required=True, parser_class=Parser)
    ls = sub.add_parser("list", help="list algorithms, envs and suites (or one of them: harness list envs)")
    ls.add_argument("what", nargs="?", choices=LIST_PARTS)
    ls.set_defaults(fn=cmd_list)

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
    f.add_argument("--dest", help="target directory (default: the project cache; also dest=DIR)")
    f.add_argument("--base-url", default=data_mod.EARL_REPO_URL, help="also base_url=URL")
    f.add_argument("overrides", nargs="*")
    s = dsub.add_parser("scripted", help="generate demonstrations with the scripted experts",
                        epilog=keys_help(keys.SCRIPTED, False), formatter_class=raw)
    s.add_argument("overrides", nargs="*")
    d.set_defaults(fn=cmd_data)

    b = sub.add_parser("bench", help="benchmarks: env and training throughput, network products, dashboard page-load "
                                      "time")
    bsub = b.add_subparsers(dest="what", required=True, parser_class=Parser)
    for what, table in keys.BENCH.items():  # each with its own keys in its --help
        one = bsub.add_parser(what, help=BENCH_HELP[what], epilog=keys_help(table, False), formatter_class=raw)
        one.add_argument("overrides", nargs="*")
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
    words = flag_words(words)
    if len(words) == 1 and words[0] in ("data", "bench"):  # a command of several: its help, not an argparse error
        parser.parse_args([words[0], "--help"])
    args, extra = parser.parse_known_args(words)
    if extra:
        if not hasattr(args, "overrides"):
            parser.parse_args(words)  # the usual argparse error for what is really unknown
        flags = [w for w in extra if w.startswith("-")]
        if flags:  # name only the unknown flags, not the key=value words that followed them
            from harness.words import did_you_mean

            command = " ".join(["harness", args.cmd, *([args.data_cmd] if getattr(args, "data_cmd", None) else [])])
            hint = (f" ({flags[0].split('=', 1)[0]} is not a flag of `{command}`)" if flags[0].split("=", 1)[0] in FLAGS
                    else did_you_mean(flags[0], FLAGS))
            print(f"harness: error: unknown flag(s) {' '.join(flags)}{hint} (see `{command} --help`)", file=sys.stderr)
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
