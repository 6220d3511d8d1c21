import ctypes.util
import os
import signal

import numpy as np
import pytest
import torch

# headless rendering through OSMesa where Debian's libosmesa6 is installed. Without it, MUJOCO_GL=osmesa would make
# `import mujoco` fail for every test and GLFW with no display aborts the process, so GL is switched off and the
# rendering tests skip (they turn "no backend" into a skip)
if ctypes.util.find_library("OSMesa"):
    os.environ.setdefault("MUJOCO_GL", "osmesa")
elif not os.environ.get("DISPLAY"):
    os.environ.setdefault("MUJOCO_GL", "disable")

# the Ctrl-C tests send SIGINT to a harness subprocess. A shell without job control starts a background job (`pytest &`)
# with SIGINT ignored, children inherit that, and Python then never raises KeyboardInterrupt: the run would finish
# (exit 0) or hang. Give the children a terminal's disposition: a handled signal is reset to the default on exec
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


# What a user has done before must not change a test's outcome (issue 57): the speed calibration that `--dry-run`
# caches, data written by `harness data fetch` / `harness data scripted` into the project cache, a HARNESS_* variable
# of the user's shell. So the session pins its data to one EARL data directory (HARNESS_TEST_DATA_DIR if set, else the
# first of HARNESS_DATA_DIR, the project cache and ../shared/earl whose demos are EARL's own, never scripted ones),
# and every test gets an empty cache and state directory of its own (the `isolated_user_state` fixture below).
# Subprocesses (workers, CLI runs) inherit the environment, so they see the same.
def _earl_data_dir():
    from harness import data

    if os.environ.get("HARNESS_TEST_DATA_DIR"):
        return os.environ["HARNESS_TEST_DATA_DIR"]
    cands = [os.environ["HARNESS_DATA_DIR"]] if os.environ.get("HARNESS_DATA_DIR") else []
    cands += [str(d) for _, d in data.candidate_dirs(None) if str(d) not in cands]
    for d in cands:
        try:
            if all(data.load_demos(env, direction, data_dir=d).source == "earl"
                   for env in data.ENV_NAMES for direction in data.DIRECTIONS):
                return d
        except (data.DataNotFoundError, OSError, ValueError):
            continue
    return None


for _k in ("HARNESS_RESULTS", "HARNESS_CACHE_DIR", "HARNESS_STATE_DIR", "HARNESS_TEST_RAY_KILL_ONCE"):
    os.environ.pop(_k, None)  # the user's shell settings are not the tests' (HARNESS_CHROMIUM, a tool's path, stays)
if (_data := _earl_data_dir()) is not None:
    os.environ["HARNESS_DATA_DIR"] = str(_data)
else:  # no EARL data: the tests that need it skip; none may find the user's scripted demos instead
    os.environ["HARNESS_DATA_DIR"] = os.path.join(os.path.dirname(__file__), "no-earl-data")


@pytest.fixture(autouse=True)
def isolated_user_state(tmp_path_factory, monkeypatch):
    """An empty project cache and state directory (calibration) for each test."""
    base = tmp_path_factory.mktemp("user_state")
    monkeypatch.setenv("HARNESS_CACHE_DIR", str(base / "cache"))
    monkeypatch.setenv("HARNESS_STATE_DIR", str(base / "state"))
    yield base


def _has_data() -> bool:
    from harness.data import DataNotFoundError, find_data_dir

    try:
        find_data_dir("demos")
        return True
    except DataNotFoundError:
        return False


requires_data = pytest.mark.skipif(not _has_data(), reason="EARL data directory not found")


@pytest.fixture(autouse=True)
def one_thread():
    """Tiny networks: intra-op threads only add overhead, and stall badly on a busy 2-core machine."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def rollout_actions(algo, env: str, seeds, steps: int) -> np.ndarray:
    """Drive ``algo`` through the protocol's own step for ``steps`` steps; the actions taken (T, E, A)."""
    from harness.protocol import Interaction

    inter = Interaction(env, list(seeds))
    inter.start(algo)
    out = []
    for _ in range(steps):
        inter.step(algo)
        out.append(algo._action.copy())
    return np.stack(out)
