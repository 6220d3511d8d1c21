"""Data directory search order, demo loading, `harness data fetch` against a local HTTP server."""

import functools
import http.server
import pickle
import threading
from pathlib import Path

import numpy as np
import pytest

from algorithms.api import DEMO_FIELDS
from harness import data as data_mod
from harness.cli import main
from harness.data import DataNotFoundError, find_data_dir, load_demos

from .conftest import requires_data

SHARED = data_mod.PROJECT_ROOT.parent / "shared" / "earl"


def _fake_data_dir(root: Path) -> Path:
    (root / "demos").mkdir(parents=True)
    return root


def test_search_order(tmp_path, monkeypatch):
    explicit = _fake_data_dir(tmp_path / "explicit")
    cache = _fake_data_dir(tmp_path / "cache")
    monkeypatch.setenv("HARNESS_CACHE_DIR", str(cache))
    monkeypatch.delenv("HARNESS_DATA_DIR", raising=False)
    assert find_data_dir("demos", explicit=explicit) == explicit
    monkeypatch.setenv("HARNESS_DATA_DIR", str(explicit))
    assert find_data_dir("demos") == explicit
    monkeypatch.delenv("HARNESS_DATA_DIR")
    assert find_data_dir("demos") == cache  # cache before ../shared/earl


def test_not_found_is_one_clear_line(tmp_path, monkeypatch):
    monkeypatch.setenv("HARNESS_CACHE_DIR", str(tmp_path / "none"))
    monkeypatch.setattr(data_mod, "PROJECT_ROOT", tmp_path / "proj")
    monkeypatch.delenv("HARNESS_DATA_DIR", raising=False)
    with pytest.raises(DataNotFoundError) as e:
        find_data_dir("demos")
    msg = str(e.value)
    assert "\n" not in msg and "harness data fetch" in msg and "HARNESS_DATA_DIR" in msg and "cache" in msg
    # the published curves are not among what `harness data fetch` brings: the line says so, and how to go on
    with pytest.raises(DataNotFoundError) as e:
        find_data_dir("reference/published_curves.csv.gz")
    msg = str(e.value)
    assert "\n" not in msg and "not something `harness data fetch` downloads" in msg and "published=none" in msg
    with pytest.raises(DataNotFoundError) as e:  # the same with one directory named (HARNESS_DATA_DIR, --data-dir)
        find_data_dir("reference/published_curves.csv.gz", explicit=tmp_path)
    assert "not something `harness data fetch` downloads" in str(e.value) and str(tmp_path) in str(e.value)
    # an explicit directory is the only place searched: no silent fallback to the others
    for explicit in (tmp_path / "missing", tmp_path):
        with pytest.raises(DataNotFoundError) as e:
            find_data_dir("demos", explicit=explicit)
        msg = str(e.value)
        assert "\n" not in msg and str(explicit) in msg and "harness data fetch" in msg
        assert ("does not exist" if explicit.name == "missing" else "has no 'demos'") in msg


@requires_data
def test_load_demos_typed_and_split():
    counts = {
        ("tabletop_manipulation", "forward"): (12, 1278, 12),
        ("sawyer_door", "reverse"): (5, 700, 14),
        ("sawyer_peg", "reverse"): (20, 1132, 14),
    }
    for (env, d), (n_traj, n, obs_dim) in counts.items():
        demos = load_demos(env, d)
        assert len(demos) == n and demos.observations.shape == (n, obs_dim)
        assert demos.rewards.shape == (n,) and demos.terminals.dtype == bool
        trajs = demos.trajectories()
        assert len(trajs) == n_traj
        for tr in trajs:  # each trajectory ends at its only rewarded, terminal transition
            assert tr["terminals"][-1] and tr["terminals"].sum() == 1 and tr["rewards"].sum() == 1
            np.testing.assert_array_equal(tr["observations"][1:], tr["next_observations"][:-1])
    assert demos.source == "earl"


@pytest.fixture
def earl_mirror(tmp_path):
    """A directory laid out like the EARL GitHub repository (demo pickles + tabletop assets)."""
    root = tmp_path / "mirror"
    for env in data_mod.ENV_NAMES:
        for d in data_mod.DIRECTIONS:
            with np.load(SHARED / "demos" / env / f"{d}.npz") as z:
                payload = {k: z[k] for k in DEMO_FIELDS}
            payload["infos"] = []
            p = root / data_mod.remote_demo_path(env, d)
            p.parent.mkdir(parents=True)
            p.write_bytes(pickle.dumps(payload))
    assets = root / "earl_benchmark" / "envs" / "tabletop_assets"
    assets.mkdir(parents=True)
    for name in data_mod.TABLETOP_ASSET_FILES:
        (assets / name).write_bytes((SHARED / "assets" / "tabletop" / name).read_bytes())
    for remote, local, names in (("metaworld_assets", "metaworld_earl", data_mod.SAWYER_ASSET_FILES),
                                 ("kitchen_assets", "kitchen", data_mod.KITCHEN_ASSET_FILES),
                                 ("minitaur_assets", "minitaur", data_mod.MINITAUR_ASSET_FILES)):
        for name in names:
            p = root / "earl_benchmark" / "envs" / remote / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes((SHARED / "assets" / local / name).read_bytes())
    return root


@pytest.fixture
def http_server(earl_mirror):
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(earl_mirror))
    handler.log_message = lambda *a, **k: None
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    t = threading.Thread(target=srv.serve_forever, daemon=True)
    t.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}"
    srv.shutdown()


@requires_data
def test_fetch_from_local_http_server(http_server, tmp_path, monkeypatch, capsys):
    dest = tmp_path / "cache"
    assert main(["data", "fetch", "--dest", str(dest), "--base-url", http_server]) == 0
    for env in data_mod.ENV_NAMES:
        for d in data_mod.DIRECTIONS:
            got, ref = load_demos(env, d, data_dir=dest), load_demos(env, d, data_dir=SHARED)
            for k in DEMO_FIELDS:
                np.testing.assert_array_equal(getattr(got, k), getattr(ref, k))
    assert (dest / "assets" / "tabletop" / "tabletop_manipulation.xml").exists()
    # the Sawyer, kitchen and minitaur models too: every env runs from a fetched cache
    for local in ("metaworld_earl", "kitchen", "minitaur"):
        ref = sorted(p.relative_to(SHARED / "assets" / local) for p in (SHARED / "assets" / local).rglob("*")
                     if p.is_file())
        got = sorted(p.relative_to(dest / "assets" / local) for p in (dest / "assets" / local).rglob("*") if p.is_file())
        assert got == ref and all((dest / "assets" / local / p).read_bytes() == (SHARED / "assets" / local / p)
                                  .read_bytes() for p in ref), local
    assert not list(dest.rglob("*.tmp"))
    monkeypatch.setenv("HARNESS_CACHE_DIR", str(dest))
    monkeypatch.delenv("HARNESS_DATA_DIR", raising=False)
    assert find_data_dir("demos") == dest  # the cache is found next time


def test_fetch_without_network_is_one_line_naming_the_ways_on(tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert main(["data", "fetch", f"dest={tmp_path / 'd'}", f"base_url=http://127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cannot download" in err and "harness data scripted" in err and "--data-dir" in err
    assert not (tmp_path / "d" / "demos").exists() or not list((tmp_path / "d").rglob("*.npz"))


def test_fetch_refuses_non_numpy_pickles(tmp_path):
    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    with pytest.raises(pickle.UnpicklingError):
        data_mod.demo_pickle_to_arrays(pickle.dumps({"observations": Evil()}))


def test_scripted_demos_cli(tmp_path):
    out = tmp_path / "scripted"
    assert main(["data", "scripted", "env=tabletop_manipulation", f"out={out}"]) == 0
    demos = load_demos("tabletop_manipulation", "reverse", data_dir=out)
    assert demos.source == "scripted" and len(demos.trajectories()) == 12
    np.testing.assert_array_equal(demos.observations[0, 6:], [0, 0, 2.5, 0, -1, -1])  # goal = rho0


def test_scripted_data_runs_every_env_without_network_or_earl_data(tmp_path, capsys):
    """Offline, `harness data scripted` writes what the Sawyer envs need too: EARL's model files, rebuilt from the
    installed Meta-World's and checked against EARL's SHA-256 (so byte-identical to EARL's copies), then a run works
    with that directory as the only data."""
    from harness.envs.sawyer_assets import EARL_SHA256, earl_file

    d = tmp_path / "offline"
    assert main(["--data-dir", str(d), "data", "scripted", "env=sawyer_door", f"out={d}"]) == 0
    assert sorted(p.relative_to(d / "assets" / "metaworld_earl").as_posix()
                  for p in (d / "assets" / "metaworld_earl").rglob("*") if p.is_file()) == sorted(EARL_SHA256)
    if (SHARED / "assets" / "metaworld_earl").is_dir():
        for name in data_mod.SAWYER_ASSET_FILES:
            assert (d / "assets" / "metaworld_earl" / name).read_bytes() == \
                (SHARED / "assets" / "metaworld_earl" / name).read_bytes(), name
    assert load_demos("sawyer_door", "forward", data_dir=d).source == "scripted"
    assert main(["--data-dir", str(d), "run", "algo=naive", "env=sawyer_door", "steps=200", "eval_every=100",
                 "eval_episodes=1", "all.seed_steps=100", "all.batch_size=16", f"results={tmp_path / 'r'}"]) == 0
    assert f"the demonstrations of sawyer_door are scripted (`harness data scripted`, in {d})" in capsys.readouterr().err
    # a Meta-World file that no longer rebuilds EARL's is one line naming it, nothing written
    bad = tmp_path / "mw"
    (bad / "objects" / "assets").mkdir(parents=True)
    (bad / "objects" / "assets" / "xyz_base.xml").write_text("<mujocoinclude/>")
    with pytest.raises(data_mod.DataNotFoundError, match="does not rebuild EARL's objects/assets/xyz_base.xml"):
        earl_file("objects/assets/xyz_base.xml", bad)


@pytest.mark.parametrize(
    "argv, needle",
    [
        (["data", "scripted", "env=nope"], "unknown env 'nope'"),
        (["data", "scripted", "colour=red"], "unknown key 'colour'"),
        (["data", "scripted", "seed=-1"], "seed must be >= 0"),
        (["bench", "env", "steps=abc"], "steps must be an integer"),
        (["bench", "env", "envs=foo"], "unknown env 'foo'"),
        (["bench", "matmul", "members=0"], "members must be >= 1"),
        (["bench", "matmul", "size=3"], "unknown key 'size'"),
    ],
)
def test_bad_input_one_line_exit_2(argv, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and needle in err
    assert not list(tmp_path.iterdir())  # nothing written


@requires_data
def test_published_deployed_values_are_returns_on_kitchen_dhand_and_minitaur():
    from harness.results import load_published

    p = load_published()
    kinds = p[p["metric"].str.startswith("deployed")].groupby("env")["metric"].unique().map(sorted)
    assert kinds["kitchen"] == kinds["minitaur"] == kinds["dhand_lightbulb"] == ["deployed_return"]
    assert kinds["sawyer_peg"] == kinds["tabletop_manipulation"] == ["deployed_success"]
    assert p.loc[(p["env"] == "kitchen") & (p["metric"] == "deployed_return"), "value"].min() < -1  # returns, not rates


def test_a_results_write_on_a_full_disk_says_so_and_leaves_the_old_file(tmp_path, monkeypatch):
    import errno

    from harness import data as D

    target = tmp_path / "evals.parquet"
    target.write_bytes(b"old rows")

    def no_space(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(D.os, "fsync", no_space)
    with pytest.raises(OSError, match=r"the disk of .* is full .* while writing evals.parquet: free space, then run"):
        D.atomic_write_bytes(target, b"new rows")
    assert target.read_bytes() == b"old rows" and [p.name for p in tmp_path.iterdir()] == ["evals.parquet"]
