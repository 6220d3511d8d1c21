"""Fingerprint what training produces, to show a refactor leaves every result bit for bit unchanged.

    python scripts/fingerprint.py OUT.json [algo=medal,risc] [update=default,compiled] [env=tabletop_manipulation]
                                           [steps=1500] [eval_every=500]
    python scripts/fingerprint.py --compare BEFORE.json AFTER.json

For each (algorithm, update mode) it runs ``harness run`` with a tiny budget (two seeds trained as two members of one
process, updates on after 500 steps where the method has a seed phase, an evaluation every 500 steps) into a
temporary directory and records sha256 hashes of: the evaluation rows, the training-diagnostics rows (both without the
wall-clock metrics and the git SHA), and every tensor of the final checkpoint (weights, optimizer state, random
streams). ``--compare`` prints the rows that differ and exits 1 if any does.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import pandas as pd
import torch

from harness.provenance import state_digest

WALL_METRICS = {"steps_per_s", "wall_s", "eta_s"}
STEPS, EVAL_EVERY, SEED_STEPS = 1500, 500, 500


def _hash_bytes(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()[:16]


def _hash_rows(paths: list[Path]) -> str:
    frame = pd.concat([pd.read_parquet(p) for p in sorted(paths)], ignore_index=True)
    frame = frame[~frame["metric"].isin(WALL_METRICS)].drop(columns=["git_sha"])
    frame = frame.sort_values(["seed", "step", "metric"]).reset_index(drop=True)
    return _hash_bytes(frame.to_csv(index=False, float_format="%.9g").encode() + frame["value"].to_numpy().tobytes())


def _hash_checkpoint(path: Path) -> str:
    state = torch.load(path, map_location="cpu", weights_only=False)
    return state_digest({k: v for k, v in state.items() if k not in ("wall_s", "git_sha", "command", "versions", "time")})


def fingerprint(algo: str, update: str, env: str, steps: int = STEPS, eval_every: int = EVAL_EVERY) -> dict:
    from harness.registry import ALGORITHMS

    seed_phase = [f"{algo}.seed_steps={SEED_STEPS}"] if "seed_steps" in ALGORITHMS[algo].Config.keys() else []
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "harness.cli", "run", f"algo={algo}", f"env={env}", "seeds=2", "members=2",
               f"steps={steps}", f"eval_every={eval_every}", *seed_phase, f"update={update}",
               "workers=1", f"results={tmp}", "eval_episodes=2"]
        proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
        if proc.returncode:
            raise SystemExit(f"{algo}/{update}: harness run failed:\n{proc.stderr[-2000:]}")
        runs = Path(tmp) / "adhoc" / env / algo
        checkpoints = sorted(runs.glob("checkpoints/*/checkpoint.pt"))
        return {"algo": algo, "update": update, "env": env,
                "evals": _hash_rows(list(runs.glob("seed=*/evals.parquet"))),
                "train": _hash_rows(list(runs.glob("seed=*/train.parquet"))),
                "checkpoint": _hash_checkpoint(checkpoints[-1]) if checkpoints else None}


def main(argv: list[str]) -> int:
    if argv[:1] == ["--compare"]:
        before, after = (json.loads(Path(p).read_text()) for p in argv[1:3])
        key = lambda r: (r["algo"], r["update"], r["env"])  # noqa: E731
        old = {key(r): r for r in before}
        bad = 0
        for r in after:
            o = old.get(key(r))
            same = o is not None and all(o[k] == r[k] for k in ("evals", "train", "checkpoint"))
            bad += not same
            print(f"{'same' if same else 'DIFFERS'}  {r['algo']:12s} {r['update']:9s} {r['env']}")
        return 1 if bad else 0
    out, words = Path(argv[0]), dict(w.split("=", 1) for w in argv[1:])
    from harness.registry import ALGORITHMS

    algos = words.get("algo", ",".join(ALGORITHMS)).split(",")
    updates = words.get("update", "default").split(",")
    env = words.get("env", "tabletop_manipulation")
    rows = []
    for algo in algos:
        for update in updates:
            rows.append(fingerprint(algo, update, env, int(words.get("steps", STEPS)),
                                    int(words.get("eval_every", EVAL_EVERY))))
            print(json.dumps(rows[-1]), flush=True)
    out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
