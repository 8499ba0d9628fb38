"""What a run writes as it goes: the history CSV and the frame schedule of the ParaView series.

* :class:`History` appends one row per ``history_every`` steps (rank 0) and flushes it; on a
  restart it first drops the rows after the checkpoint's step, so a restarted run has no
  duplicated rows.
* :class:`FrameSchedule` spaces frames evenly in *time*, k t_end / frames, so that remeshes
  (which change dt) and restarts keep the requested count and spacing.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Dict, Optional

from .io import OutputError, failures


class History:
    """``history.csv`` of a run (rank 0 writes; other ranks only compute the row)."""

    def __init__(self, path: Path, comm, restart_step: Optional[int] = None):
        self.path = Path(path)
        self.comm = comm
        self._file = None
        self._writer = None
        self._mode = "w"
        self.error = None  # rank 0's first failed row of those written with collective=False
        if restart_step is not None and comm.rank == 0 and self.path.exists():
            with open(self.path, newline="") as f:
                rows = list(csv.reader(f))
            keep = rows[:1] + [r for r in rows[1:] if r and int(float(r[0])) <= restart_step]
            with open(self.path, "w", newline="") as f:
                csv.writer(f).writerows(keep)
            self._mode = "a" if keep else "w"

    def write(self, row: Dict, collective: bool = True):
        """Append ``row``.  ``collective``: every rank learns at once whether rank 0 wrote it (an
        :class:`~hydrofrac.io.OutputError` on every rank if not).  Otherwise (the time loop's
        rows, which a collective per row would make every rank wait for rank 0 at every step):
        rank 0 keeps its first error and writes no more rows, and :meth:`check` raises it."""
        if collective:
            errors = failures(self.comm, lambda: self._write(row))
            if errors:
                raise self.failure("; ".join(errors))
        elif self.comm.rank == 0 and self.error is None:
            try:
                self._write(row)
            except Exception as e:  # (raised on every rank by check)
                self.error = f"rank 0: {type(e).__name__}: {e}"

    def _write(self, row: Dict):
        if self.comm.rank != 0:
            return
        if self._writer is None:
            self._file = open(self.path, self._mode, newline="")
            self._writer = csv.DictWriter(self._file, fieldnames=list(row))
            if self._mode == "w":
                self._writer.writeheader()
        self._writer.writerow(row)
        self._file.flush()

    def check(self):
        """Collective: an :class:`~hydrofrac.io.OutputError` on every rank if a row written with
        ``collective=False`` failed on rank 0."""
        error = self.comm.bcast(self.error, root=0)
        if error is not None:
            raise self.failure(error)

    def failure(self, errors: str) -> OutputError:
        return OutputError(f"could not write {self.path}: {errors}. Free disk space or choose a writable --out")

    def close(self):
        if self._file is not None:
            self._file.close()
            self._file = self._writer = None


class FrameSchedule:
    """Frame k (1..frames) is written at the first step that reaches k t_end / frames."""

    def __init__(self, t_end: float, frames: int, done: int = 0):
        self.t_end, self.frames, self.done = t_end, frames, done

    def due(self, t: float, dt: float) -> bool:
        """Is a frame due at time ``t`` (after a step of ``dt``)?  Counts it if so."""
        if self.done >= self.frames:
            return False
        nxt = (self.done + 1) * self.t_end / self.frames
        if t >= nxt - 1e-9 * dt:
            # a step longer than the spacing writes one frame, not several
            self.done = min(self.frames, max(self.done + 1, int(math.floor(t / self.t_end * self.frames + 1e-9))))
            return True
        return False
