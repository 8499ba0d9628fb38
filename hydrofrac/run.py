"""The time loop every scenario uses: output as it goes, progress, checkpoints,
restart, blow-up detection and the closing summary (``summary.json``).

A run never loses what it computed: frames and the history CSV are written as
the run goes; a blow-up stops the run, writes the last good state (a frame and
a checkpoint) and raises :class:`~hydrofrac.solver.BlowUpError`; ``restart=True``
continues from the last checkpoint in the output folder.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, Optional

import numpy as np

from . import compat
from .io import VTKSeries, bulk_part
from .solver import BlowUpError, Solver


@dataclass(frozen=True)
class RunOptions:
    """Options of a run.

    t_end : simulated time [s]
    out : output folder
    frames : number of output frames (plus the initial one)
    checkpoint_wall : seconds of wall time between checkpoints
    restart : continue from ``out/checkpoint`` if present
    progress_wall : seconds of wall time between progress lines (rank 0)
    history_every : steps between history rows
    """

    t_end: float
    out: str = "results/run"
    frames: int = 20
    checkpoint_wall: float = 120.0
    restart: bool = False
    progress_wall: float = 10.0
    history_every: int = 1

    def __post_init__(self):
        if not (isinstance(self.t_end, (int, float)) and self.t_end > 0 and math.isfinite(self.t_end)):
            raise ValueError(f"t_end must be a positive time in seconds; got {self.t_end!r}")
        if not (isinstance(self.frames, int) and self.frames >= 1):
            raise ValueError(f"frames must be an integer >= 1; got {self.frames!r}")
        if self.history_every < 1:
            raise ValueError(f"history_every must be >= 1; got {self.history_every}")


def scenario_parser(description: str) -> argparse.ArgumentParser:
    """The command-line options every scenario script accepts."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--quick", action="store_true", help="seconds-long size (used by the tests)")
    p.add_argument("--out", default=None, help="output folder (default results/<scenario>)")
    p.add_argument("--degree", "-p", type=int, default=None, help="polynomial degree 1..4")
    p.add_argument("--t-end", type=float, default=None, help="simulated time [s]")
    p.add_argument("--frames", type=int, default=None, help="number of output frames")
    p.add_argument("--restart", action="store_true", help="continue from the last checkpoint in --out")
    return p


def log(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


def _fmt_time(s):
    s = int(max(s, 0))
    return f"{s // 3600:d}:{s % 3600 // 60:02d}:{s % 60:02d}"


class Checkpoint:
    """Per-rank ``.npz`` files with the state vector, interface states and budgets.

    A restart needs the same mesh and the same number of ranks (the DOLFINx
    numbering of a partition is deterministic); both are checked.
    """

    def __init__(self, out: Path, comm):
        self.dir = out / "checkpoint"
        self.comm = comm

    def path(self, rank=None):
        return self.dir / f"state_r{self.comm.rank if rank is None else rank}.npz"

    def save(self, solver: Solver, series: VTKSeries, frames_done: int, x=None, t=None, step=None, ext_states=None,
             geometry=""):
        if self.comm.rank == 0:
            self.dir.mkdir(parents=True, exist_ok=True)
        self.comm.barrier()
        x = solver.x if x is None else x
        ext = [e.checkpoint_state() for e in solver.extensions] if ext_states is None else ext_states
        data = dict(x=x.array_r.copy(), t=solver.t if t is None else t, step=solver.step_count if step is None else step,
                    ranks=self.comm.size, ndofs=solver.num_dofs, frames_done=frames_done,
                    energy=json.dumps(solver.energy.__dict__), frames=json.dumps(series.frames),
                    last_rates=json.dumps(solver._last_rates), geometry=geometry,
                    mesh_check=_mesh_checksum(solver))
        for i, e in enumerate(ext):
            for k, v in e.items():
                data[f"ext{i}_{k}"] = v
        tmp = self.dir / f".tmp_r{self.comm.rank}.npz"
        np.savez(tmp, **data)
        tmp.replace(self.path())
        self.comm.barrier()

    def exists(self):
        return all(self.comm.allgather(self.path().exists()))

    def geometry(self):
        """The crack-geometry state saved with the checkpoint ("" for a run that does not
        remesh)."""
        d = np.load(self.path(), allow_pickle=False)
        return str(d["geometry"]) if "geometry" in d.files else ""

    def load(self, solver: Solver, series: VTKSeries):
        d = np.load(self.path(), allow_pickle=False)
        if int(d["ranks"]) != self.comm.size or int(d["ndofs"]) != solver.num_dofs:
            raise ValueError(f"checkpoint in {self.dir} was written by {int(d['ranks'])} ranks with "
                             f"{int(d['ndofs'])} DOFs; this run has {self.comm.size} ranks and {solver.num_dofs} DOFs. "
                             "Restart with the same mesh, degree and number of ranks")
        if "mesh_check" in d.files and not np.isclose(float(d["mesh_check"]), _mesh_checksum(solver), rtol=1e-12):
            raise ValueError(f"checkpoint in {self.dir} was written on a different mesh or partition (same number "
                             "of DOFs, other cells on this rank). Restart with the same mesh and number of ranks")
        solver.x.array[:] = d["x"]
        solver.t = float(d["t"])
        solver.step_count = int(d["step"])
        for k, v in json.loads(str(d["energy"])).items():
            setattr(solver.energy, k, v)
        rates = json.loads(str(d["last_rates"]))
        solver._last_rates = None if rates is None else tuple(rates)
        for i, e in enumerate(solver.extensions):
            e.restore_state({k.split("_", 1)[1]: d[k] for k in d.files if k.startswith(f"ext{i}_")})
        series.restore(json.loads(str(d["frames"])))
        return int(d["frames_done"])


def _mesh_checksum(solver):
    """A number that changes with the cells (and their order) of this rank's part of the mesh."""
    v = compat.cell_vertex_coords(solver.mesh)[: compat.num_cells_local(solver.mesh)]
    return float((v.reshape(len(v), -1) * np.arange(1, 7)).sum() + np.arange(len(v)) @ v[:, 0, 0])


def run(solver: Solver, options: RunOptions, name: str = "solution",
        extra_parts: Optional[Callable[[], Dict]] = None,
        history_extra: Optional[Callable[[], Dict[str, float]]] = None,
        accuracy: Optional[Callable[[Solver], Dict]] = None,
        on_step: Optional[Callable[[Solver], None]] = None,
        remesh: Optional[Callable[[Solver], Optional[Solver]]] = None) -> Dict:
    """Integrate ``solver`` to ``options.t_end``; returns the summary dictionary.

    extra_parts : returns more output parts per frame (e.g. the crack interface)
    history_extra : returns more history columns per row
    accuracy : returns the run's accuracy measures (errors against known answers)
    on_step : called after every step (e.g. crack growth, connectivity updates)
    remesh : called after every step; returns a new solver (fields and state transferred,
        e.g. :class:`hydrofrac.growth.GrowthDriver`) to continue with, or None.  Its time is
        reported as "remesh" in the split and the number of remeshes in the summary.  If it
        has ``checkpoint_state()`` (JSON text) and ``restart(text) -> solver``, checkpoints
        hold the crack geometry too, and a restart rebuilds that mesh before loading the fields.
    """
    comm = solver.comm
    out = Path(options.out)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    series = VTKSeries(out, name, comm)
    ckpt = Checkpoint(out, comm)
    nsteps = max(1, int(math.ceil(options.t_end / solver.dt - 1e-9)))
    frame_every = max(1, nsteps // options.frames)
    frames_done = 0
    history_path = out / "history.csv"
    def geometry():
        return remesh.checkpoint_state() if remesh is not None and hasattr(remesh, "checkpoint_state") else ""

    if options.restart and ckpt.exists():
        saved = ckpt.geometry()
        if saved:
            if remesh is None or not hasattr(remesh, "restart"):
                raise ValueError(f"checkpoint in {ckpt.dir} is of a run that remeshed (crack growth); restart it "
                                 "with the same growth options")
            solver = remesh.restart(saved)  # the mesh of the checkpoint's crack geometry
        frames_done = ckpt.load(solver, series)
        if saved:  # the step count continues on the last mesh's time step (as after a remesh)
            nsteps = solver.step_count + max(1, int(math.ceil((options.t_end - solver.t) / solver.dt - 1e-9)))
            frame_every = max(1, (nsteps - solver.step_count) // max(1, options.frames - frames_done))
        log(comm, f"[hydrofrac] restarted from {ckpt.dir} at step {solver.step_count}, t = {solver.t:.6g} s")
        hist_mode = "a"
    else:
        if options.restart:
            log(comm, f"[hydrofrac] no checkpoint in {ckpt.dir}; starting from t = 0")
        hist_mode = "w"

    def parts():
        p = {"bulk": bulk_part(solver)}
        if extra_parts is not None:
            p.update(extra_parts())
        return p

    def history_row():
        e = solver.energy
        row = {"step": solver.step_count, "t": solver.t, "kinetic": e.kinetic, "strain": e.strain,
               "work_in": e.work_in, "radiated": e.radiated, "dissipated_flux": e.dissipated_flux,
               "dissipated_friction": e.dissipated_friction, "dissipated_damage": e.dissipated_damage,
               "balance_error": e.balance_error}
        if history_extra is not None:
            row.update(history_extra())
        return row

    hist_file = None
    writer = None

    def write_history():
        nonlocal hist_file, writer
        row = history_row()
        if comm.rank == 0:
            if writer is None:
                hist_file = open(history_path, hist_mode, newline="")
                writer = csv.DictWriter(hist_file, fieldnames=list(row))
                if hist_mode == "w":
                    writer.writeheader()
            writer.writerow(row)
            hist_file.flush()

    log(comm, f"[hydrofrac] {name}: {solver.num_cells} cells, {solver.num_dofs} DOFs, p = {solver.degree}, "
              f"{comm.size} rank(s), dt = {solver.dt:.4g} s, {nsteps} steps to t = {options.t_end:.4g} s")
    if solver.step_count == 0:
        solver.update_energy()
        t0 = time.perf_counter()
        series.write(solver.t, parts())
        solver.timers.add("output", time.perf_counter() - t0)
        write_history()

    good_x = solver.x.copy()
    good = (solver.t, solver.step_count, [e.checkpoint_state() for e in solver.extensions])
    wall0 = time.perf_counter()
    last_progress = last_ckpt = wall0
    step0 = solver.step_count
    remeshes = 0
    work = 0.0  # DOF*stages done (the mesh may change)
    try:
        while solver.step_count < nsteps:
            solver.step()
            solver.update_energy()
            solver.check_stability()
            work += solver.num_dofs * solver.num_stages
            if on_step is not None:
                on_step(solver)
            if remesh is not None:
                t0 = time.perf_counter()
                try:
                    new = remesh(solver)
                except Exception as err:  # e.g. Gmsh cannot mesh the extended geometry
                    series.write(solver.t, parts())
                    ckpt.save(solver, series, frames_done + 1, geometry=geometry())
                    msg = (f"[hydrofrac] remeshing after crack growth failed at t = {solver.t:.6g} s: {err}\n"
                           f"[hydrofrac] stopped. The last good state (before the extension) is in "
                           f"{series.pvd_path} and {ckpt.dir}")
                    log(comm, msg)
                    if hist_file is not None:
                        hist_file.close()
                    raise RuntimeError(msg) from err
                if new is not None:
                    solver = new
                    nsteps = solver.step_count + max(1, int(math.ceil((options.t_end - solver.t) / solver.dt - 1e-9)))
                    frame_every = max(1, (nsteps - solver.step_count) // max(1, options.frames - frames_done))
                    good_x = solver.x.copy()
                    remeshes += 1
                    solver.timers.add("remesh", time.perf_counter() - t0)
            solver.x.copy(good_x)
            good = (solver.t, solver.step_count, [e.checkpoint_state() for e in solver.extensions])
            if solver.step_count % options.history_every == 0 or solver.step_count == nsteps:
                t0 = time.perf_counter()
                write_history()
                solver.timers.add("output", time.perf_counter() - t0)
            if solver.step_count % frame_every == 0 or solver.step_count == nsteps:
                t0 = time.perf_counter()
                series.write(solver.t, parts())
                frames_done += 1
                solver.timers.add("output", time.perf_counter() - t0)
            now = time.perf_counter()
            if now - last_ckpt > options.checkpoint_wall:
                ckpt.save(solver, series, frames_done, geometry=geometry())
                last_ckpt = now
            if now - last_progress > options.progress_wall and comm.rank == 0:
                done = solver.step_count - step0
                eta = (now - wall0) / max(done, 1) * (nsteps - solver.step_count)
                rate = solver.num_dofs * solver.num_stages * done / (now - wall0)
                print(f"[hydrofrac] step {solver.step_count}/{nsteps}  t = {solver.t:.4e} s  "
                      f"({100 * solver.step_count / nsteps:.0f}%)  {rate:.3g} DOF*stages/s  ETA {_fmt_time(eta)}",
                      flush=True)
                last_progress = now
    except BlowUpError as err:
        t_bad = solver.t
        good_x.copy(solver.x)
        solver.t, solver.step_count = good[0], good[1]
        for e, st in zip(solver.extensions, good[2]):
            e.restore_state(st)
        series.write(solver.t, parts())
        ckpt.save(solver, series, frames_done + 1, geometry=geometry())
        msg = (f"{err}\n[hydrofrac] stopped. The last good state (t = {solver.t:.6g} s, before the blow-up at "
               f"t = {t_bad:.6g} s) is in {series.pvd_path} and {ckpt.dir}")
        log(comm, msg)
        if hist_file is not None:
            hist_file.close()
        raise BlowUpError(msg) from None
    wall = time.perf_counter() - wall0
    ckpt.save(solver, series, frames_done, geometry=geometry())
    if hist_file is not None:
        hist_file.close()

    steps_run = solver.step_count - step0
    summary = solver.summary()
    summary.update({
        "scenario": name,
        "wall_time_s": wall,
        "setup_time_s": solver.timers.t.get("setup", 0.0),
        "dof_stages_per_s": work / wall if wall > 0 else float("nan"),
        "dof_stages_per_s_per_rank": work / wall / comm.size if wall > 0 else float("nan"),
        "energy": solver.energy.as_dict(),
        "time_split_s": {k: comm.allreduce(v, op=compat.MPI.MAX) for k, v in solver.timers.t.items()},
        "output": {"paraview": str(series.pvd_path), "history": str(history_path), "checkpoint": str(ckpt.dir)},
    })
    summary["cost_us"] = unit_costs(solver, steps_run)
    if remesh is not None:
        t_rm = solver.timers.t.get("remesh", 0.0)
        summary["remeshing"] = {"remeshes": remeshes, "wall_s": t_rm, "share": t_rm / wall if wall > 0 else 0.0}
    if accuracy is not None:
        summary["accuracy"] = accuracy(solver)
    if comm.rank == 0:
        with open(out / "summary.json", "w") as f:
            json.dump(summary, f, indent=2, default=float)
        print_summary(summary)
    return summary


def unit_costs(solver, steps: int) -> Dict[str, float]:
    """Wall time per unit of work, summed over ranks [µs]: the bulk operator per
    cell*stage and the interface kernel per crack facet*stage (issue 3's comparison)."""
    comm = solver.comm
    stages = solver.num_stages * max(steps, 1)
    t = solver.timers.t
    cells = compat.num_cells_local(solver.mesh)
    facets = sum(e.facets.size for e in solver.extensions if hasattr(e, "facets"))
    loc = np.array([t.get("bulk operator", 0.0), cells, t.get("interface kernel", 0.0), facets], dtype=float)
    tot = np.zeros(4)
    comm.Allreduce(loc, tot, op=compat.MPI.SUM)
    out = {"bulk_per_cell_stage": 1e6 * tot[0] / max(tot[1] * stages, 1)}
    if tot[3] > 0:
        out["interface_per_facet_stage"] = 1e6 * tot[2] / (tot[3] * stages)
        out["crack_facets"] = int(tot[3])
    return out


def print_summary(s: Dict, file=sys.stdout):
    e = s["energy"]
    lines = [
        f"[hydrofrac] ---- summary: {s['scenario']} ----",
        f"  mesh        {s['cells']} cells, {s['dofs']} DOFs, p = {s['degree']}, {s['ranks']} rank(s)",
        f"  time        {s['steps']} steps of dt = {s['dt']:.4g} s ({s['scheme']}, CFL {s['cfl']:.3g}) "
        f"to t = {s['simulated_time']:.6g} s",
        f"  speed       wall {s['wall_time_s']:.2f} s (+ setup {s['setup_time_s']:.2f} s), "
        f"{s['dof_stages_per_s']:.3g} DOF*stages/s ({s['dof_stages_per_s_per_rank']:.3g} per rank)",
        f"  energy      kinetic {e['kinetic']:.5g}, strain {e['strain']:.5g}, work in {e['work_in']:.5g}, "
        f"radiated {e['radiated']:.5g}, dissipated (flux {e['dissipated_flux']:.4g}, friction "
        f"{e['dissipated_friction']:.4g}, damage {e['dissipated_damage']:.4g}) J/m",
        f"  balance     error {e['balance_error']:.3g} J/m ({e['balance_error_relative']:.2e} relative)",
        "  time split  " + ", ".join(f"{k} {v:.2f} s" for k, v in s["time_split_s"].items()),
    ]
    c = s.get("cost_us")
    if c:
        line = f"  unit cost   bulk operator {c['bulk_per_cell_stage']:.3g} us per cell*stage"
        if "interface_per_facet_stage" in c:
            line += (f", interface kernel {c['interface_per_facet_stage']:.3g} us per crack facet*stage "
                     f"({c['crack_facets']} crack facets)")
        lines.append(line)
    if "remeshing" in s:
        r = s["remeshing"]
        lines.append(f"  remeshing   {r['remeshes']} remeshes, {r['wall_s']:.2f} s ({100 * r['share']:.0f}% of the wall time)")
    for k, v in s.get("accuracy", {}).items():
        lines.append(f"  accuracy    {k} = {v:.4g}" if isinstance(v, float) else f"  accuracy    {k} = {v}")
    lines.append(f"  output      {s['output']['paraview']} (ParaView), {s['output']['history']}")
    print("\n".join(lines), file=file, flush=True)
