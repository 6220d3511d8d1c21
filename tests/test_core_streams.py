"""The table of random-stream ids (``algorithms.core.nets.Stream``): frozen values, no id shared by two streams of one
run, and no stream id written as a bare number anywhere in ``algorithms/``."""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch

from algorithms.core import nets
from algorithms.core.nets import Stream, stream_seed

from .conftest import requires_data

ROOT = Path(__file__).resolve().parent.parent
NETS = ROOT / "algorithms" / "core" / "nets.py"

#: today's ids; changing one changes every result drawn from that stream (and what checkpoints continue)
FROZEN = {
    "SAC_ACT": 1, "SAC_UPDATE": 2, "MIXUP": 5, "TASK_GOALS": 7, "REPLAY": 10, "BACKWARD_REPLAY": 11,
    "EXPERT_STATES": 12, "AGENT_STATES": 13, "GC_REPLAY": 20, "GC_GOALS": 21, "GC_WARMUP": 22, "SUCCESS_CRITIC": 30,
    "SWITCH": 33, "VALUE_CRITIC": 40, "RELABEL": 43, "SAC_VALUE": 44, "RND_INIT": 30, "DAC_INIT": 40, "DAC_NOISE": 41,
}
#: entries that hand an AuxCritic (algorithms/goal_conditioned.py) its base id: it also draws from base + 1, base + 2
AUX_BASES = ("SUCCESS_CRITIC", "VALUE_CRITIC")
#: calls whose stream id is a positional argument: name -> its index
STREAM_ARG = {"member_generators": 2, "member_rngs": 1, "stream_seed": 1, "AuxCritic": 5, "StateBuffer": 5,
              "SegmentReplayBuffer": 7}
SEEDING = {"default_rng", "SeedSequence", "manual_seed", "seed"}


def table() -> dict[str, int]:
    return {k: v for k, v in vars(Stream).items() if k.isupper()}


def owners_and_aliases() -> tuple[set[str], set[str]]:
    """Entries written as a number own their id; entries written in terms of another entry are declared reuses."""
    cls = next(n for n in ast.parse(NETS.read_text()).body if isinstance(n, ast.ClassDef) and n.name == "Stream")
    owners, aliases = set(), set()
    for node in cls.body:
        if isinstance(node, ast.Assign):
            literal = isinstance(node.value, ast.Constant) and isinstance(node.value.value, int)
            (owners if literal else aliases).update(t.id for t in node.targets)
    return owners, aliases


def test_stream_ids_are_frozen():
    assert table() == FROZEN
    assert all(type(v) is int for v in table().values())  # plain ints: seeding and checkpoints see no enum type


def test_owned_stream_ids_are_distinct():
    """No two owned ids coincide, counting the two extra ids each AuxCritic base takes; every other entry is an
    explicit reuse (``X = OTHER``) by a method that never runs with OTHER's owner."""
    owners, aliases = owners_and_aliases()
    assert owners | aliases == set(table()) and not owners & aliases
    ids = [table()[k] for k in owners] + [table()[k] + d for k in AUX_BASES for d in (1, 2)]
    assert [i for i, n in Counter(ids).items() if n > 1] == []
    assert aliases == {"RND_INIT", "DAC_INIT", "DAC_NOISE"}


def _bare_number(node: ast.AST | None) -> bool:
    """A literal integer, or arithmetic on literals only (``3``, ``-1``, ``10 + 2``)."""
    if node is None:
        return False
    parts = list(ast.walk(node))
    return all(isinstance(n, (ast.Constant, ast.BinOp, ast.UnaryOp, ast.operator, ast.unaryop)) for n in parts) \
        and any(isinstance(n, ast.Constant) and isinstance(n.value, int) for n in parts)


def _call_name(call: ast.Call) -> str:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else ""


def bare_stream_ids(source: str) -> list[str]:
    """Every place in ``source`` where a stream id (or a seed derived outside the table) is a bare number."""
    bad = []
    for node in ast.walk(ast.parse(source)):
        where = f"line {getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Call):
            name = _call_name(node)
            bad += [f"{where}: {name}(stream=...)" for k in node.keywords
                    if k.arg == "stream" and _bare_number(k.value)]
            i = STREAM_ARG.get(name)
            if i is not None and len(node.args) > i and _bare_number(node.args[i]):
                bad.append(f"{where}: {name}(...) stream argument")
            if name in SEEDING and any(_bare_number(a) or isinstance(a, (ast.List, ast.Tuple))
                                       and any(_bare_number(e) for e in a.elts) for a in node.args):
                bad.append(f"{where}: {name}(...) with a literal seed")
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            named = [*zip(a.args[len(a.args) - len(a.defaults):], a.defaults), *zip(a.kwonlyargs, a.kw_defaults)]
            bad += [f"{where}: default {p.arg}=..." for p, d in named if p.arg == "stream" and _bare_number(d)]
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = [n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)]
            if any("STREAM" in n.upper() for n in names) and node.value is not None \
                    and any(_bare_number(n) for n in ast.walk(node.value)):
                bad.append(f"{where}: {', '.join(names)} = <number>")
    return bad


def test_the_bare_stream_id_finder_finds_them():
    src = """
x = member_generators(seeds, "cpu", 30)
y = member_rngs(seeds, stream=7)
z = StateBuffer(E, n, d, device, seeds, stream=10 + 2, name="x")
a = AuxCritic(o, a, seeds, cfg, device, 40)
r = np.random.default_rng([s, 7])
def f(stream: int = 20): ...
FOO_STREAM, BAR_STREAM = 1, 2
ok = member_generators(seeds, device, Stream.SAC_ACT), member_rngs(seeds, stream=Stream.TASK_GOALS)
ok2 = member_generators(seeds, device, stream + 1), np.random.default_rng([s, stream])
"""
    assert len(bare_stream_ids(src)) == 7


def test_no_stream_id_is_a_bare_number_in_algorithms():
    bad = {}
    for p in sorted((ROOT / "algorithms").rglob("*.py")):
        source = p.read_text()
        if p == NETS:  # the table itself (the class body) is where the numbers live
            cls = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "Stream")
            lines = source.splitlines()
            source = "\n".join("" if cls.lineno <= i + 1 <= cls.end_lineno else line for i, line in enumerate(lines))
        found = bare_stream_ids(source)
        if found:
            bad[str(p.relative_to(ROOT))] = found
    assert bad == {}


@pytest.fixture
def drawn(monkeypatch):
    """Record the seed of every random stream the algorithms open: ('torch', manual_seed value) per member generator
    and ('numpy', entropy) per member numpy Generator, with the stream id that produced it."""
    import algorithms.common as common

    log: list[tuple[str, object, int | None]] = []
    real_gens, real_rngs = nets.member_generators, common.member_rngs

    def member_generators(seeds, device="cpu", stream=None):
        log.extend([("torch", int(s) if stream is None else stream_seed(int(s), stream), stream) for s in seeds])
        return real_gens(seeds, device, stream)

    def member_rngs(seeds, stream):
        log.extend([("numpy", (int(s), int(stream)), stream) for s in seeds])
        return real_rngs(seeds, stream)

    for name, mod in list(sys.modules.items()):
        if name == "algorithms" or name.startswith("algorithms."):
            if getattr(mod, "member_generators", None) is real_gens:
                monkeypatch.setattr(mod, "member_generators", member_generators)
            if getattr(mod, "member_rngs", None) is real_rngs:
                monkeypatch.setattr(mod, "member_rngs", member_rngs)
    return log


@requires_data
def test_no_run_draws_two_streams_from_one_seed(drawn):
    """Every registered method, built as harness builds it: no two of a member's random streams share a seed, and every
    stream id it uses is in the table (or one of an AuxCritic base's two extra ids). Member seed 5: the forward /
    backward agents' derived seeds (2s, 2s + 1) then differ from the member's own."""
    from algorithms.api import DemoSet
    from harness.data import load_demos
    from harness.envs import get_spec
    from harness.registry import ALGORITHMS

    env = "tabletop_manipulation"
    spec, demos = get_spec(env), DemoSet(load_demos(env, "forward"), load_demos(env, "reverse"))
    known = set(table().values()) | {table()[k] + d for k in AUX_BASES for d in (1, 2)}
    for name, cls in ALGORITHMS.items():
        drawn.clear()
        cls(spec, demos, cls.Config(), [5], torch.device("cpu"))
        seeds = Counter((kind, seed) for kind, seed, _ in drawn)
        assert [k for k, n in seeds.items() if n > 1] == [], name
        assert {s for _, _, s in drawn} - {None} <= known, name
        assert any(s is not None for _, _, s in drawn), name


def test_member_rngs_and_stream_seed_take_plain_ints():
    """The table's ints seed exactly as the literals did (the values are what matter, not the names)."""
    from algorithms.common import member_rngs

    assert stream_seed(3, Stream.SAC_UPDATE) == stream_seed(3, 2)
    a, b = member_rngs([3], Stream.TASK_GOALS)[0], np.random.default_rng([3, 7])
    assert a.integers(1 << 30, size=4).tolist() == b.integers(1 << 30, size=4).tolist()
