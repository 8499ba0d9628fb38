"""Checkpoints: what a restarted run needs to end exactly as a straight run does.

One ``.npz`` file per rank in ``out/checkpoint``: the state vector, time and step, the
interface states, the energy budget, the output series, the crack geometry of a remeshing
run, the monitors' records, the loop's counters, the run's parameters and the rank count.
Every decision about a checkpoint is collective:

* the loop decides *when* to save on rank 0's clock (or a step count) and broadcasts it;
* before a restart every rank reads its whole file, and all ranks agree that every piece is
  readable and consistent before any rank uses it; a bad checkpoint is the same clear
  :class:`CheckpointError` on every rank, naming the file and what to do;
* a save that fails on any rank (a full disk, no write permission) is the same
  :class:`CheckpointError` on every rank, and leaves the previous checkpoint in place;
* a save keeps each rank's previous file (``state_r<rank>.prev.npz``) until its new one is in
  place, so a run killed while the ranks replace their files (some new, some old) restarts from
  the newest step that every rank still has, never from files of different steps.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, Optional

import numpy as np

from . import compat
from .io import failures

REQUIRED = ("x", "t", "step", "ranks", "ndofs", "frames_done", "energy", "frames", "last_rates", "geometry",
            "mesh_check", "params", "monitors", "loop")


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used for this run (damaged, other ranks or parameters)."""


def dumps(obj) -> str:
    """JSON text of objects with numpy arrays (read back by :func:`loads`)."""
    return _json(obj)


def _json(obj) -> str:
    return json.dumps(obj, default=_np_default)


def _np_default(o):
    if isinstance(o, np.ndarray):
        return {"__ndarray__": o.tolist(), "dtype": str(o.dtype)}
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serialisable")


def _np_hook(d):
    if "__ndarray__" in d:
        return np.array(d["__ndarray__"], dtype=d["dtype"])
    return d


def loads(text: str):
    """JSON text with numpy arrays (as written by the checkpoint) back to objects."""
    return json.loads(text, object_hook=_np_hook)


def mesh_checksum(solver) -> float:
    """A number that changes with the cells (and their order) of this rank's part of the mesh."""
    v = compat.cell_vertex_coords(solver.mesh)[: compat.num_cells_local(solver.mesh)]
    return float((v.reshape(len(v), -1) * np.arange(1, 7)).sum() + np.arange(len(v)) @ v[:, 0, 0])


class Checkpoint:
    """The per-rank checkpoint files of a run in ``out``."""

    def __init__(self, out: Path, comm):
        self.dir = Path(out) / "checkpoint"
        self.comm = comm

    def path(self, rank=None, previous=False) -> Path:
        r = self.comm.rank if rank is None else rank
        return self.dir / (f"state_r{r}.prev.npz" if previous else f"state_r{r}.npz")

    def _replace(self, tmp):
        """This rank's new file in place, its current one kept as the previous generation."""
        if self.path().exists():
            self.path().replace(self.path(previous=True))
        tmp.replace(self.path())

    # ------------------------------------------------------------------ save
    def save(self, problem, frames, frames_done: int, params: Dict, monitors, loop, geometry: str = "",
             snapshot=None):
        """Write every rank's file (collective: all ranks call it at the same step).
        ``frames``: the output series' frame list; ``monitors``, ``loop``: JSON-able objects or
        their JSON text.  ``snapshot``: (x, t, step, energy, last_rates, extension states) to
        save instead of the problem's current state (the last good state after a blow-up, the
        state before a shortened last step)."""
        solver = problem.solver
        mkdir = (lambda: self.dir.mkdir(parents=True, exist_ok=True)) if self.comm.rank == 0 else (lambda: None)
        self._on_every_rank(mkdir, "create the folder")
        if snapshot is None:
            snapshot = (solver.x.array_r, solver.t, solver.step_count, solver.energy.__dict__,
                        solver.account.last_rates,
                        [e.checkpoint_state() for e in solver.extensions])
        x, t, step, energy, rates, ext = snapshot
        data = dict(x=np.array(x), t=t, step=step, ranks=self.comm.size, ndofs=solver.num_dofs,
                    frames_done=frames_done, energy=json.dumps(energy), frames=json.dumps(frames),
                    last_rates=json.dumps(rates), geometry=geometry, mesh_check=mesh_checksum(solver),
                    params=_json(params), monitors=monitors if isinstance(monitors, str) else _json(monitors),
                    loop=loop if isinstance(loop, str) else _json(loop))
        for i, e in enumerate(ext):
            for k, v in e.items():
                data[f"ext{i}_{k}"] = v
        tmp = self.dir / f".tmp_r{self.comm.rank}.npz"
        # every rank has its new file before any replaces its old one; a rank that cannot write
        # leaves every rank's previous checkpoint in place
        self._on_every_rank(lambda: np.savez(tmp, **data), "write its file", cleanup=lambda: tmp.unlink(missing_ok=True))
        self._on_every_rank(lambda: self._replace(tmp), "replace its file",
                            kept="a restart uses the newest step every rank's files still hold")

    def _on_every_rank(self, action, what, cleanup=None, kept="the previous checkpoint, if any, is kept"):
        """Run ``action`` on this rank and agree on the outcome (collective): if it failed on
        any rank, every rank runs ``cleanup`` and raises the same :class:`CheckpointError`,
        naming the ranks and their errors, so no rank waits in a later collective for one that
        has stopped (a full disk, a folder without write permission)."""
        errors = failures(self.comm, action)
        if errors:
            if cleanup is not None:
                cleanup()
            raise CheckpointError(f"checkpoint in {self.dir}: could not {what} ({'; '.join(errors)}). The run stops "
                                  f"here with its output so far; {kept}. Free disk space or choose a writable "
                                  "--out, then restart")

    # ------------------------------------------------------------------ read and validate
    def _read_own(self, previous=False):
        """(status, data or message) of this rank's file (or its previous generation): 'none'
        (absent), 'ok' or 'bad'."""
        p = self.path(previous=previous)
        if not p.exists():
            return "none", f"{p} is missing"
        try:
            with np.load(p, allow_pickle=False) as d:
                data = {k: d[k] for k in d.files}  # reads (and decompresses) every piece
            missing = [k for k in REQUIRED if k not in data]
            if missing:
                return "bad", f"{p} lacks {missing} (written by an older hydrofrac?)"
            for k in ("energy", "frames", "last_rates", "geometry", "params", "monitors", "loop"):
                data[k] = str(data[k])
            loads(data["params"]), loads(data["monitors"]), loads(data["loop"]), json.loads(data["energy"])
            return "ok", data
        except Exception as err:  # truncated, garbage, not a zip: one message for all of them
            return "bad", f"{p} cannot be read ({type(err).__name__}: {err})"

    def read(self, ndofs: Optional[int] = None) -> Optional[Dict]:
        """This rank's checkpoint data, validated on every rank together; None where no rank
        has a checkpoint.  Raises :class:`CheckpointError` (on every rank) for a damaged
        checkpoint, one written by another number of ranks, or one whose ranks disagree."""
        status, data = self._read_own()

        def meta_of(status, data):
            return (status, data if status != "ok" else None,
                    None if status != "ok" else (int(data["ranks"]), float(data["t"]), int(data["step"])))

        allm = self.comm.allgather(meta_of(status, data))
        whole = all(m[0] == "ok" for m in allm) and len({m[2][1:] for m in allm}) == 1
        if not whole and not any(m[0] == "bad" for m in allm):
            # the ranks' files of different steps, or some or all missing: a save interrupted
            # while the ranks replaced their files (each moves its file to the previous generation,
            # then its new one into place); the newest step every rank still has, from either one
            prev = self._read_own(previous=True)
            allp = self.comm.allgather(meta_of(*prev))
            have = [{m[2][1:] for m in pair if m[0] == "ok"} for pair in zip(allm, allp)]
            common = set.intersection(*have)
            if common:
                newest = max(common, key=lambda tk: tk[1])
                mine = meta_of(status, data)[2]
                if mine is None or mine[1:] != newest:
                    status, data = prev
                allm = self.comm.allgather(meta_of(status, data))
                if self.comm.rank == 0:
                    print(f"[hydrofrac] the last checkpoint save was interrupted; restarting from step {newest[1]}, "
                          "the newest one every rank's files hold", flush=True)
        if all(m[0] == "none" for m in allm):
            others = sorted(p for p in self.dir.glob("state_r*.npz") if not p.name.endswith(".prev.npz")) \
                if self.dir.exists() else []
            if others:  # files of other ranks only: a checkpoint of more ranks
                raise CheckpointError(f"checkpoint in {self.dir} was not written by this run's {self.comm.size} "
                                      f"rank(s) (files: {', '.join(p.name for p in others)}); restart with the "
                                      "number of ranks that wrote it, or remove the folder to start anew")
            return None
        ranks = {m[2][0] for m in allm if m[0] == "ok"}
        if len(ranks) == 1 and ranks != {self.comm.size}:
            n = ranks.pop()
            raise CheckpointError(f"checkpoint in {self.dir} was written by {n} rank(s); this run has "
                                  f"{self.comm.size}. Restart with mpirun -n {n}, or remove the folder to start anew")
        bad = [m[1] for m in allm if m[0] != "ok"]
        if bad:
            raise CheckpointError(f"checkpoint in {self.dir} is damaged: " + "; ".join(bad)
                                  + ". Remove the folder to start anew (the run's other output is kept)")
        if len({m[2][1:] for m in allm}) != 1 or ranks != {self.comm.size}:
            raise CheckpointError(f"checkpoint in {self.dir}: the ranks' files are of different steps or rank "
                                  "counts (an interrupted save?). Remove the folder to start anew")
        if ndofs is not None:
            self.check_mesh(data, ndofs, None)
        return data

    def check_mesh(self, data: Dict, ndofs: int, solver):
        """The checkpoint's DOF count and mesh partition are this run's (collective)."""
        ok = int(data["ndofs"]) == ndofs
        if ok and solver is not None:
            ok = bool(np.isclose(float(data["mesh_check"]), mesh_checksum(solver), rtol=1e-12))
        if not all(self.comm.allgather(ok)):
            raise CheckpointError(f"checkpoint in {self.dir} was written on a different mesh, degree or partition "
                                  f"({int(data['ndofs'])} DOFs; this run {ndofs}). Restart with the same mesh, degree "
                                  "and number of ranks, or remove the folder to start anew")

    @staticmethod
    def load_into(data: Dict, problem, series):
        """Set the problem's state and the output series from validated checkpoint data."""
        solver = problem.solver
        solver.x.array[:] = data["x"]
        solver.t = float(data["t"])
        solver.step_count = int(data["step"])
        for k, v in json.loads(data["energy"]).items():
            setattr(solver.energy, k, v)
        rates = json.loads(data["last_rates"])
        solver.account.last_rates = None if rates is None else tuple(rates)
        for i, e in enumerate(solver.extensions):
            e.restore_state({k.split("_", 1)[1]: data[k] for k in data if k.startswith(f"ext{i}_")})
        problem.after_restore()
        series.restore(json.loads(data["frames"]))
