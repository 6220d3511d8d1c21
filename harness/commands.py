"""What each ``harness`` command does with its parsed words (:mod:`harness.cli` parses the command line and calls
these): ``list``, ``data``, ``bench``, ``run``, ``report``, ``ship``, ``status`` and ``tune``. Heavy modules load
inside each command, so ``--help``, ``list`` and usage errors answer before torch is imported."""

from __future__ import annotations

import sys
from pathlib import Path

from harness import command_keys as keys
from harness import data as data_mod
from harness.words import UsageError, boolean, optional_integer, parse_words


def parse_overrides(items: list[str], allowed: set[str] | None = None) -> dict[str, str]:
    """``key=value`` words into a dict (values stay strings; callers validate)."""
    return parse_words(items, allowed)[0]


def _csv(v: str | None) -> list[str] | None:
    return [x for x in v.split(",") if x] if v else None


LIST_PARTS = ("algorithms", "algos", "algo", "envs", "env", "suites", "suite")


def cmd_list(args) -> int:
    from harness.catalogue import algorithm_summaries
    from harness.envs import ENVS, UNAVAILABLE_ENVS
    from harness.suites import list_suites, load_suite

    part = (args.what or "all").rstrip("s").replace("algorithm", "algo")
    if part in ("all", "algo"):
        print("algorithms:")
        for name, doc in algorithm_summaries().items():
            print(f"  {name:<14} {doc}")
    if part in ("all", "env"):
        print("envs:")
        for name, info in ENVS.items():
            why = info.unavailable()  # an optional simulator not installed
            print(f"  {name:<22} {why}" if why else f"  {name:<22} {info.spec.gym_id}")
        for name, why in UNAVAILABLE_ENVS.items():
            print(f"  {name:<22} {why}")
    if part in ("all", "suite"):
        print("suites:")
        suites = list_suites()
        width = max(map(len, suites), default=0) + 1
        for name in suites:
            print(f"  {name:<{width}} {load_suite(name)[1].get('description', '')}")
    return 0


def cmd_data(args) -> int:
    if args.data_cmd == "fetch":
        ov = parse_overrides(args.overrides, {"dest", "base_url"})
        dest = ov.get("dest") or args.dest
        out = data_mod.fetch(dest=Path(dest) if dest else None, base_url=ov.get("base_url") or args.base_url)
        print(f"EARL demonstrations written to {out}")
        return 0
    if args.data_cmd == "scripted":
        from harness.envs import ENVS, env_info, env_name
        from harness.envs.experts import generate_demos

        ov = parse_overrides(args.overrides, {"env", *keys.SCRIPTED})
        envs = [env_name(e) for e in _csv(ov.get("envs") or ov.get("env")) or []] or [
            e for e, info in ENVS.items() if info.experts]
        for e in envs:
            env_info(e)  # unknown or never released: one line
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
        from harness.envs import check_env, env_name

        ov = parse_overrides(args.overrides, {"env", *keys.BENCH["env"]})
        envs = [env_name(e) for e in _csv(ov.get("envs") or ov.get("env")) or []] or None
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
        from harness.words import did_you_mean, name_of

        known = sorted(df["suite"].dropna().astype(str).unique()) if not df.empty else []
        suite = name_of(ov["suite"], known, parts=False)
        if suite not in known:
            raise UsageError(f"no runs of suite {ov['suite']!r} under {results}{did_you_mean(ov['suite'], known)}; "
                             f"suites with runs there: {', '.join(known) or 'none'}")
        df = df[df["suite"] == suite]
    print(status_text(df))
    return 0


def cmd_tune(args) -> int:
    from harness.tune.command import tune_cli

    return tune_cli(args.overrides, best=args.best)


