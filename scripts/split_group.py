"""Split a run group's checkpoint (E seeds trained as members of one process) into E single-seed checkpoints, so that
each seed resumes in a process of its own (``harness run`` then plans one group per seed: harness.packing.seed_groups).

    python scripts/split_group.py CHECKPOINT            # .../<algo>/checkpoints/seeds=0-1/checkpoint.pt

Why: a step of a forward-backward method (MEDAL, FBRL, R3L) updates only each member's acting controller, so members
in different phases run every controller's update (docs/performance.md): one seed per process trains faster. Every
member of a group is the run it would be alone (to float rounding), so member i's part of the
state is a single-seed run's state: per-member lists (seeds, random streams, envs, last successes) give their i-th
item, member-major tensors (leading dimension E * k) their i-th block, and an optimizer's flat moments the i-th slice
of each parameter's segment (algorithms.core.optim.FlatMembers). ``tests/test_split_group.py`` checks that the split
seeds resume exactly as the group would have gone on. The group's checkpoint is kept, renamed ``seeds=a-b.split``.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

#: lists with one item per member
PER_MEMBER_LISTS = {"seeds", "act_generators", "update_generators", "generators", "rngs", "envs", "last_success"}
#: an optimizer's state key -> the sibling key of the parameters it covers (their order is the flat layout's)
OPTIMIZED = {"actor_opt": "actor", "critic_opt": "critic", "alpha_opt": "log_alpha", "opt": "net"}


def _block(x, E: int, i: int, where: str):
    if x.ndim == 0 or x.shape[0] % E:
        raise ValueError(f"{where}: leading dimension {tuple(x.shape)} is not a multiple of {E} members")
    k = x.shape[0] // E
    out = x[i * k : (i + 1) * k]
    return out.clone() if isinstance(out, torch.Tensor) else out.copy()


def _optimizer(opt: dict, params: Any, E: int, i: int, where: str) -> dict:
    shapes = [p.shape for p in params.values()] if isinstance(params, dict) else [params.shape]
    out = dict(opt)
    for key in ("exp_avg", "exp_avg_sq"):
        flat, parts, offset = opt[key], [], 0
        for shape in shapes:
            n = int(np.prod(shape))
            parts.append(flat[offset : offset + n].view(E, -1)[i])
            offset += n
        if offset != flat.numel():
            raise ValueError(f"{where}/{key}: {flat.numel()} values, its parameters hold {offset}")
        out[key] = torch.cat(parts).clone()
    out["step"] = _block(opt["step"], E, i, f"{where}/step")
    return out


def member_state(state: Any, E: int, i: int, where: str = "") -> Any:
    """Member ``i``'s part of a group's state (a checkpoint or any part of it)."""
    if isinstance(state, dict):
        out = {}
        for k, v in state.items():
            w = f"{where}/{k}"
            if k in OPTIMIZED and isinstance(v, dict) and "exp_avg" in v:
                if OPTIMIZED[k] not in state:
                    raise ValueError(f"{w}: no {OPTIMIZED[k]!r} beside it to read the optimizer's layout from")
                out[k] = _optimizer(v, state[OPTIMIZED[k]], E, i, w)
            elif k in PER_MEMBER_LISTS and isinstance(v, list):
                if len(v) != E:
                    raise ValueError(f"{w}: {len(v)} items for {E} members")
                out[k] = [v[i]]
            elif k == "config" or k in ("lr", "betas", "eps", "bit_generator"):
                out[k] = v
            else:
                out[k] = member_state(v, E, i, w)
        return out
    if isinstance(state, (torch.Tensor, np.ndarray)):
        return _block(state, E, i, where)
    if isinstance(state, (list, tuple)):
        raise ValueError(f"{where}: a {type(state).__name__} this script does not know how to split")
    return state  # scalars: the step, the wall time, the device


def split(checkpoint: Path) -> list[Path]:
    seeds = [int(s) for s in checkpoint.parent.name.removeprefix("seeds=").split("-")]
    if len(seeds) < 2:
        raise SystemExit(f"{checkpoint}: a group of one seed; nothing to split")
    ck = torch.load(checkpoint, map_location="cpu", weights_only=False)
    written = []
    for i, seed in enumerate(seeds):
        path = checkpoint.parent.parent / f"seeds={seed}" / checkpoint.name
        if path.exists():
            raise SystemExit(f"{path} exists already; not overwritten")
        one = member_state(ck, len(seeds), i)
        path.parent.mkdir(parents=True)
        torch.save(one, path.with_suffix(".tmp"))
        path.with_suffix(".tmp").rename(path)
        written.append(path)
    checkpoint.parent.rename(checkpoint.parent.with_name(checkpoint.parent.name + ".split"))
    return written


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    for p in split(Path(sys.argv[1]).expanduser()):
        print(p)
