import os

import pytest

os.environ.setdefault("MUJOCO_GL", "osmesa")


def _has_data() -> bool:
    from harness.data import DataNotFoundError, find_data_dir

    try:
        find_data_dir("demos")
        return True
    except DataNotFoundError:
        return False


requires_data = pytest.mark.skipif(not _has_data(), reason="EARL data directory not found")
