"""The key=value words of ``harness report``, ``ship``, ``bench`` and ``data scripted``: (default, meaning) per key.

Each command accepts exactly its table's keys, and ``harness <command> --help`` prints the table. The CLI builds
every subcommand's help on each call, so this module imports nothing the CLI does not load anyway."""

from __future__ import annotations

from algorithms.update_modes import UPDATES

KeyHelp = dict[str, tuple[str, str]]

DENORMALS_HELP = ("keep: IEEE gradual underflow, torch's default, as training runs; flush: subnormal floats read and "
                  "written as zero (harness.backends.flush_denormals), for comparison")

CURVE_METRICS = ("deployed_success", "deployed_return", "continuing_reward", "interventions")
PUBLISHED_SOURCES = ("risc_paper", "earl_benchmark")

REPORT: KeyHelp = {
    "suite": ("all runs", "a suite's runs only (a suite with cells also gets the reproduction verdicts)"),
    "results": ("results", "results directory to read"),
    "out": ("<results>/report/<suite or all>", "directory the figures and tables are written to"),
    "metric": ("deployed_success", "curve metric: " + ", ".join(CURVE_METRICS)
               + " (deployed_return when every env publishes returns: kitchen, minitaur)"),
    "step": ("last", "Table 1's step: last (each run's last evaluation), matched (the largest step every run in the "
                     "env reached) or N (the last evaluation at or before N)"),
    "smooth": ("1", "moving average over K evaluations, curves only"),
    "published": ("risc_paper", "published curves beside ours: " + ", ".join(PUBLISHED_SOURCES)
                                + " (comma list), or none; earl_benchmark is added for kitchen"),
    "doc": ("none", "a Markdown file whose <!-- table:SUITE --> table is rewritten, figure drawn beside it"),
}
SHIP: KeyHelp = {
    "suite": ("required", "the suite whose runs are shipped"),
    "results": ("required", "where they ran"),
    "to": ("results", "the results directory they are copied to"),
    "force": ("false", "replace a shipped table even where the run in results= got less far"),
}
STATUS: KeyHelp = {
    "results": ("results", "the results directory whose runs are shown"),
    "suite": ("all", "show only this suite's runs"),
}
SCRIPTED: KeyHelp = {
    "envs": ("every env with scripted experts", "env names (comma list; or env=)"),
    "out": ("the project cache", "directory the demos/<env>/<direction>.npz files go to"),
    "seed": ("0", "seed of the demos' resets"),
}
BENCH: dict[str, KeyHelp] = {
    "env": {"envs": ("every env", "env names (comma list; or env=)"), "steps": ("per env", "steps per repeat"),
            "repeats": ("5", "timed repeats")},
    "train": {
        "algo": ("medal", "algorithm"), "env": ("sawyer_door", "environment"),
        "members": ("1", "seeds trained in lockstep by the process"), "steps": ("1000", "timed env steps per repeat"),
        "repeats": ("3", "timed repeats (the median is reported)"), "device": ("cpu", "torch device"),
        "threads": ("torch's default", "torch threads"), "env_workers": ("0", "env worker processes"),
        "seed_steps": ("1000", "the seed phase (no updates), run untimed before the timed steps"),
        "update": ("default", "SAC updates: " + ", ".join(UPDATES)),
        "allocator": ("keep", "keep: freed heap kept for reuse, as training runs (harness.backends.keep_freed_memory); "
                              "glibc: its defaults"),
        "denormals": ("keep", DENORMALS_HELP),
        "checkpoint": ("none", "a run's checkpoint.pt: time training from that state (the run's algo, env, seeds and "
                               "config from its run.yaml; no seed phase), then print the state's digest"),
    },
    "update": {
        "algo": ("medal", "algorithm (its first SAC agent)"), "env": ("sawyer_door", "environment (obs and action sizes)"),
        "members": ("1", "seeds in the agent"), "update": ("default", "SAC updates: " + ", ".join(UPDATES)),
        "threads": ("1", "torch threads"), "repeats": ("5", "timed rounds (the median is reported)"),
        "n": ("50", "updates per round"),
        "allocator": ("keep", "keep: freed heap kept for reuse, as training runs; glibc: its defaults"),
        "denormals": ("keep", DENORMALS_HELP),
        "record": ("-", "append the result as a row (date, commit, CPU) to this Markdown file, e.g. docs/performance.md"),
    },
    "matmul": {"members": ("2", "seeds per product"), "repeats": ("5", "timed repeats")},
    "app": {"runs": ("100", "synthetic runs"), "evals": ("300", "evaluations per run"), "repeats": ("3", "page loads"),
            "results": ("a synthetic set", "results directory to load instead")},
}
