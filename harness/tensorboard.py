"""``harness run logger=tensorboard``: each run's rows also as TensorBoard scalars, in ``<run dir>/tensorboard/``.

The parquet tables stay the record; TensorBoard gets the same rows as they are written (tags ``eval/<metric>`` for
``evals.parquet`` and ``train/<metric>`` for the training diagnostics of ``train.parquet``, step = env step). A run
resumed from its checkpoint at step S purges the events after S that the stopped process had written, so TensorBoard
shows each step once, as the tables do (a run restarted from step 0 purges all earlier events). Switching to
``logger=tensorboard`` on a resumed run sends only the rows written from then on. Needs ``pip install tensorboard`` (the ``tensorboard`` extra).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any

from harness.words import ConfigError

DIRNAME = "tensorboard"


def check_available() -> None:
    if importlib.util.find_spec("tensorboard") is None:
        raise ConfigError("logger=tensorboard needs TensorBoard: pip install tensorboard (or the [tensorboard] extra)")


class TensorBoardRun:
    """One run's event writer; :meth:`tagged` gives the row sink of one table (``prefix``: eval or train)."""

    def __init__(self, run_dir: Path, resume_step: int | None):
        from torch.utils.tensorboard import SummaryWriter

        # purge_step: events at steps >= it, written before a stop, are hidden: after the checkpoint's step when
        # resuming, everything when (re)starting from step 0 (a run that died before its first checkpoint)
        purge = resume_step + 1 if resume_step is not None else 0
        self.writer = SummaryWriter(str(Path(run_dir) / DIRNAME), purge_step=purge)

    def tagged(self, prefix: str):
        def write(rows: list[dict[str, Any]]) -> None:
            for r in rows:
                self.writer.add_scalar(f"{prefix}/{r['metric']}", r["value"], r["step"])
            self.writer.flush()

        return write

    def close(self) -> None:
        self.writer.close()
