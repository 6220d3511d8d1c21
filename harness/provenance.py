"""What every run saves next to its results about where they came from: the git SHA and package versions (and
:func:`run_record`, the whole ``run.yaml``)."""

from __future__ import annotations

import importlib.metadata
import subprocess
import sys
from pathlib import Path
from typing import Any

from harness.envs import demos_record
from harness.plan import RunSpec

PACKAGES = ("torch", "numpy", "gymnasium", "mujoco", "metaworld", "pandas", "pyarrow", "earl-harness")


def git_sha(root: Path | None = None, ignore: Path | None = None) -> str:
    """HEAD's SHA, with ``-dirty`` when tracked files differ from it (the results then come from code that
    no commit holds); ``unknown`` outside a git checkout, e.g. an installed wheel. ``ignore``: a file whose changes do
    not count (the file a measurement is being recorded into)."""
    root = root or Path(__file__).resolve().parent.parent
    try:
        git = ["git", "-C", str(root)]
        sha = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True, timeout=5).stdout.strip()
        if not sha:
            return "unknown"
        skip = [f":(exclude){Path(ignore).resolve()}"] if ignore is not None else []
        dirty = subprocess.run([*git, "diff", "--quiet", "HEAD", "--", str(root), *skip], capture_output=True,
                               timeout=5).returncode == 1
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def package_versions() -> dict[str, str]:
    out = {}
    for p in PACKAGES:
        try:
            out[p] = importlib.metadata.version(p)
        except importlib.metadata.PackageNotFoundError:
            out[p] = "absent"
    return out



def run_record(spec: RunSpec, command: str) -> dict[str, Any]:
    """A group's ``run.yaml`` (each member adds its ``seed``): what ran (env, method, budget, protocol, resolved
    config and its hash, update mode), on what data (demos and their hash), by which command, from which commit, with
    which packages."""
    return {
        "suite": spec.suite, "env": spec.env, "algo": spec.algo, "algo_class": spec.algo_class, "steps": spec.steps,
        "eval_every": spec.eval_every, "eval_episodes": spec.eval_episodes, "device": spec.device,
        "group_seeds": list(spec.seeds),
        "config": spec.config, "config_hash": spec.config_hash, "demo_source": spec.demo_source,
        **demos_record(spec.env), "command": command, "git_sha": spec.git_sha, "versions": package_versions(),
        "python": sys.version.split()[0], "update": spec.update,
    }


def state_digest(state: Any) -> str:
    """sha256 (16 hex digits) of a nested state (dicts in key order, lists, tensors, numpy arrays, scalars): equal
    digests, the same state bit for bit. ``scripts/fingerprint.py`` hashes checkpoints with it; ``harness bench train
    checkpoint=`` the state its timed steps reached."""
    import hashlib
    import io

    import torch

    h = hashlib.sha256()

    def walk(prefix: str, obj: Any) -> None:
        if isinstance(obj, dict):
            for k in sorted(obj, key=str):
                walk(f"{prefix}/{k}", obj[k])
        elif isinstance(obj, (list, tuple)):
            for i, v in enumerate(obj):
                walk(f"{prefix}/{i}", v)
        elif isinstance(obj, torch.Tensor):
            h.update(prefix.encode())
            h.update(obj.detach().cpu().contiguous().numpy().tobytes() if obj.dtype != torch.bfloat16 else b"")
        elif hasattr(obj, "tobytes"):  # numpy arrays and generator states
            h.update(prefix.encode() + obj.tobytes())
        elif obj is None or isinstance(obj, (int, float, str, bool)):
            h.update(f"{prefix}={obj!r}".encode())
        else:  # anything else by its pickled bytes
            buf = io.BytesIO()
            torch.save(obj, buf)
            h.update(prefix.encode() + buf.getvalue())

    walk("", state)
    return h.hexdigest()[:16]
