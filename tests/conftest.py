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
