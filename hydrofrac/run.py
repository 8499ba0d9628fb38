"""The time loop that drives a :class:`~hydrofrac.problem.Problem`.

Each step: the RK stages (bulk operator and crack interface), the energy budget and the
stability checks, the problem's own updates (hydraulic network, pressure factor), the
monitors, an optional remesh (crack growth) that replaces the problem, then the history row,
the frame (evenly spaced in time), the checkpoint (decided collectively) and the progress
line.  The last step is shortened to land on ``t_end``.

A run never loses what it computed: frames and the history are written as the run goes; a
blow-up stops the run with the last state that passed the checks (fields, interface state
and energy budget) written as a frame and a checkpoint and raises
:class:`~hydrofrac.solver.BlowUpError`; ``restart=True`` continues from the checkpoint
(:mod:`hydrofrac.checkpoint`) and ends with the same results as a straight run.  A finished
run restarted says so and leaves its output untouched.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Mapping, Optional, Sequence

import numpy as np

from ._jit import compile_seconds
from .checkpoint import Checkpoint, CheckpointError, dumps, loads
from .io import VTKSeries
from .output import FrameSchedule, History
from .probes import ProbeWriter
from .problem import Problem
from .solver import BlowUpError, Solver
from .summary import build_summary, unit_counts, write_summary

#: steps between two readings of rank 0's clock for a checkpoint by wall time and of its history
#: writer's state (each reading is a broadcast that every rank waits for)
CLOCK_EVERY = 10


def _real(v) -> bool:
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)


@dataclass(frozen=True)
class RunOptions:
    """Options of a run.

    t_end : simulated time [s]; the last step lands on it
    out : output folder
    frames : number of output frames (plus the initial one), evenly spaced in time
    checkpoint_wall : seconds of wall time between checkpoints (rank 0's clock, read every
        :data:`CLOCK_EVERY` steps and broadcast)
    checkpoint_steps : steps between checkpoints (None: by wall time only)
    restart : continue from ``out/checkpoint`` if present
    progress_wall : seconds of wall time between progress lines (rank 0)
    history_every : steps between history rows
    params : the run's physical parameters; a restart whose parameters differ is refused
    probes : points (m, 2) whose v and σ go into ``probes.csv`` with every history row
    """

    t_end: float
    out: str = "results/run"
    frames: int = 20
    checkpoint_wall: float = 120.0
    checkpoint_steps: Optional[int] = None
    restart: bool = False
    progress_wall: float = 10.0
    history_every: int = 1
    params: Mapping = field(default_factory=dict)
    probes: Optional[Sequence[Sequence[float]]] = None

    def __post_init__(self):
        if not (_real(self.t_end) and self.t_end > 0):
            raise ValueError(f"t_end must be a positive time in seconds; got {self.t_end!r}")
        if not (isinstance(self.frames, (int, np.integer)) and self.frames >= 1):
            raise ValueError(f"frames must be an integer >= 1; got {self.frames!r}")
        if not (isinstance(self.history_every, (int, np.integer)) and self.history_every >= 1):
            raise ValueError(f"history_every must be an integer >= 1; got {self.history_every!r}")
        if not (_real(self.checkpoint_wall) and self.checkpoint_wall > 0):
            raise ValueError(f"checkpoint_wall must be > 0 s; got {self.checkpoint_wall!r}")
        if self.checkpoint_steps is not None and not (isinstance(self.checkpoint_steps, (int, np.integer))
                                                      and self.checkpoint_steps >= 1):
            raise ValueError(f"checkpoint_steps must be an integer >= 1 (or None); got {self.checkpoint_steps!r}")
        if not str(self.out):
            raise ValueError("out (the output folder) must not be empty")
        if self.probes is not None:
            pts = np.asarray(self.probes, dtype=float)
            if pts.ndim != 2 or pts.shape[1] != 2 or not len(pts) or not np.all(np.isfinite(pts)):
                raise ValueError(f"probes must be a list of (x, y) points; got {self.probes!r}")


class Monitor:
    """What watches a run.  The loop calls, with the current problem:

    * ``monitor(problem)`` after every step (after the problem's own updates);
    * ``history(problem) -> dict``: more columns of the history row;
    * ``accuracy(problem) -> dict``: the run's measures, in the summary's ``accuracy``;
    * ``remeshed(old, new)`` when a remesh replaced the problem;
    * ``report(accuracy) -> str``: a closing line, printed after the summary;
    * ``state()`` / ``restore(state)``: the record a checkpoint keeps (by default the
      attributes named in ``checkpointed``), so that a restarted run reports what a
      straight one does.
    """

    checkpointed: Sequence[str] = ()

    def __call__(self, problem):
        pass

    def history(self, problem) -> Dict:
        return {}

    def accuracy(self, problem) -> Dict:
        return {}

    def remeshed(self, old, new):
        pass

    def report(self, accuracy: Dict) -> Optional[str]:
        """A line for the end of the run (rank 0 prints it after the summary), or None."""
        return None

    def state(self) -> Dict:
        return {k: getattr(self, k) for k in self.checkpointed}

    def restore(self, state: Dict):
        for k, v in state.items():
            setattr(self, k, v)


def log(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


def _fmt_time(s):
    s = int(max(s, 0))
    return f"{s // 3600:d}:{s % 3600 // 60:02d}:{s % 60:02d}"


def _energy_row(problem) -> Dict:
    s, e = problem.solver, problem.solver.energy
    return {"step": s.step_count, "t": s.t, "kinetic": e.kinetic, "strain": e.strain, "work_in": e.work_in,
            "radiated": e.radiated, "dissipated_flux": e.dissipated_flux,
            "dissipated_friction": e.dissipated_friction, "dissipated_damage": e.dissipated_damage,
            "balance_error": e.balance_error}


def _snapshot(problem):
    """The state a blow-up falls back to: fields, time, budget, extension states."""
    s = problem.solver
    return (s.x.array_r.copy(), s.t, s.step_count, dict(s.energy.__dict__), s.account.last_rates,
            [e.checkpoint_state() for e in s.extensions])


def _restore_snapshot(problem, snap):
    s = problem.solver
    x, s.t, s.step_count, energy, s.account.last_rates, ext = snap
    s.x.array[:] = x
    for k, v in energy.items():
        setattr(s.energy, k, v)
    for e, st in zip(s.extensions, ext):
        e.restore_state(st)
    problem.after_restore()


def run(problem, options: RunOptions, name: str = "solution", monitors: Sequence[Monitor] = (),
        remesh=None) -> Dict:
    """Integrate ``problem`` (a :class:`~hydrofrac.problem.Problem`, or a bare
    :class:`~hydrofrac.solver.Solver`) to ``options.t_end``; returns the summary dictionary.

    monitors : :class:`Monitor` objects (measurements, extra history columns, accuracy)
    remesh : called with the problem after every step; returns a new problem (fields and
        state transferred, e.g. :class:`hydrofrac.growth.GrowthDriver`) or None.  Default:
        the problem's own growth driver (``problem.growth``), if any.  Its time is
        "remesh" in the split and the number of remeshes is in the summary.  With
        ``checkpoint_state()`` (JSON text) and ``restart(text) -> problem``, checkpoints hold
        the crack geometry, and a restart rebuilds that mesh before loading the fields.
    """
    if isinstance(problem, Solver):
        problem = Problem(problem)
    if remesh is None:
        remesh = problem.growth
    comm = problem.comm
    out = Path(options.out)
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    comm.barrier()
    series = VTKSeries(out, name, comm)
    ckpt = Checkpoint(out, comm)
    params = dict(options.params)
    monitors = list(monitors)
    t_end = float(options.t_end)
    loop = {"remeshes": 0, "work": 0.0}
    # the remeshes of this process, whose time the timers hold, and the work the unit costs
    # divide them by: this rank's owned cell*stages and crack facet*stages, step by step (the
    # mesh changes as cracks grow)
    timed = {"remeshes": 0, "cell_stages": 0, "facet_stages": 0}
    # (solver, owned cells, crack facets of this rank, DOF*stages and stages a step), once per mesh
    counted = [None, 0, 0, 0, 0]

    def geometry():
        return remesh.checkpoint_state() if remesh is not None and hasattr(remesh, "checkpoint_state") else ""

    def state_now():
        """Everything a checkpoint holds besides the fields, as of now."""
        return (problem, list(series.frames), frames.done, dumps([m.state() for m in monitors]), dumps(loop),
                geometry())

    def save(snapshot=None, state=None):
        history.check()  # (a checkpoint never lies beyond the last history row written)
        prob, frame_list, done, mon, lp, geom = state_now() if state is None else state
        ckpt.save(prob, frame_list, done, params, mon, lp, geom, snapshot)

    data = ckpt.read() if options.restart else None
    history_path = out / "history.csv"
    if data is not None:
        saved = loads(data["params"])
        diff = sorted(k for k in set(saved) | set(params) if saved.get(k) != params.get(k))
        if diff:
            raise CheckpointError(
                f"checkpoint in {ckpt.dir} is of a run with other parameters: "
                + ", ".join(f"{k} = {saved.get(k)!r} there, {params.get(k)!r} now" for k in diff)
                + ". Restart with the checkpoint's parameters (only --t-end may grow), or use another --out")
        finished_at = loads(data["loop"]).get("finished_at")
        if finished_at is not None and finished_at >= t_end * (1 - 1e-12):
            return _finished(comm, out, ckpt, finished_at)
        if str(data["geometry"]):
            if remesh is None or not hasattr(remesh, "restart"):
                raise CheckpointError(f"checkpoint in {ckpt.dir} is of a run that remeshed (crack growth); restart "
                                      "it with the same growth options")
            first, problem = problem, remesh.restart(str(data["geometry"]))  # the checkpoint's crack geometry
            if problem is not first:
                first.release()
        ckpt.check_mesh(data, problem.solver.num_dofs, problem.solver)
        Checkpoint.load_into(data, problem, series)
        for m, st in zip(monitors, loads(data["monitors"])):
            m.restore(st)
        loop.update(loads(data["loop"]))
        loop.pop("finished_at", None)
        frames = FrameSchedule(t_end, options.frames, int(data["frames_done"]))
        history = History(history_path, comm, restart_step=problem.solver.step_count)
        restart_step = problem.solver.step_count
        log(comm, f"[hydrofrac] restarted from {ckpt.dir} at step {problem.solver.step_count}, "
                  f"t = {problem.solver.t:.6g} s")
    else:
        if options.restart:
            log(comm, f"[hydrofrac] no checkpoint in {ckpt.dir}; starting from t = 0")
        frames = FrameSchedule(t_end, options.frames)
        history = History(history_path, comm)
        restart_step = None
    probes = None if options.probes is None else ProbeWriter(options.probes, out / "probes.csv", comm, restart_step)

    def close():
        history.close()
        if probes is not None:
            probes.close()

    def write_history(collective=True):
        row = _energy_row(problem)
        for m in monitors:
            row.update(m.history(problem))
        history.write(row, collective)
        if probes is not None:
            probes.write(problem)

    solver = problem.solver
    steps_left = max(0, int(math.ceil((t_end - solver.t) / solver.dt - 1e-9)))
    log(comm, f"[hydrofrac] {name}: {solver.num_cells} cells, {solver.num_dofs} DOFs, p = {solver.degree}, "
              f"{comm.size} rank(s), dt = {solver.dt:.4g} s, {steps_left} steps to t = {t_end:.4g} s")
    if solver.step_count == 0:
        solver.update_energy()
        t0 = time.perf_counter()
        series.write(solver.t, problem.parts())
        write_history()
        solver.timers.add("output", time.perf_counter() - t0)

    good = _snapshot(problem)
    before_last = None  # the state before a shortened last step: where a longer run continues
    retired = []  # replaced problems that before_last still holds
    wall0 = time.perf_counter()
    compiled0 = compile_seconds()  # (kernels compiled at their first use inside the loop: the summary says how long)
    last_progress = last_ckpt = wall0
    step0 = solver.step_count
    estimated = False
    try:
        while solver.t < t_end * (1 - 1e-12):
            solver = problem.solver
            dt_full = solver.dt
            last = solver.t + dt_full >= t_end * (1 - 1e-12)
            if last:  # land on t_end (a restart with another dt, or a dt that does not divide it)
                if t_end - solver.t < dt_full * (1 - 1e-9):
                    # the final checkpoint holds the state before this shortened step, so that a
                    # restart with a larger t_end continues on the straight run's steps
                    before_last = (_snapshot(problem), state_now())
                solver.dt = t_end - solver.t
            try:
                solver.step()
                if last:
                    solver.t = t_end
                solver.update_energy()
                solver.check_stability()
            finally:
                solver.dt = dt_full
            if counted[0] is not solver:
                counted[:] = [solver, *unit_counts(solver), solver.num_dofs * solver.num_stages, solver.num_stages]
            loop["work"] += counted[3]
            timed["cell_stages"] += counted[1] * counted[4]
            timed["facet_stages"] += counted[2] * counted[4]
            problem.after_step()
            if monitors:
                t0 = time.perf_counter()
                for m in monitors:
                    m(problem)
                solver.timers.add("monitors", time.perf_counter() - t0)
            if remesh is not None:
                t0 = time.perf_counter()
                try:
                    new = remesh(problem)
                except Exception as err:  # e.g. Gmsh cannot mesh the extended geometry
                    series.write(solver.t, problem.parts())
                    frames.done += 1
                    save()
                    msg = (f"[hydrofrac] remeshing after crack growth failed at t = {solver.t:.6g} s: {err}\n"
                           f"[hydrofrac] stopped. The last good state (before the extension) is in "
                           f"{series.pvd_path} and {ckpt.dir}")
                    log(comm, msg)
                    close()
                    raise RuntimeError(msg) from err
                if new is not None:
                    for m in monitors:
                        m.remeshed(problem, new)
                    old, problem = problem, new
                    solver = problem.solver
                    # the old problem's PETSc vectors, freed (petsc4py does not when Python drops
                    # them: hydrofrac.compat.destroy); the state before a shortened last step
                    # holds it until the final checkpoint
                    if before_last is not None and before_last[1][0] is old:
                        retired.append(old)
                    else:
                        old.release()
                    loop["remeshes"] += 1
                    timed["remeshes"] += 1
                    # less the criterion's time, which the driver reports itself
                    solver.timers.add("remesh", time.perf_counter() - t0 - getattr(remesh, "last_criterion_s", 0.0))
            good = _snapshot(problem)
            at_end = solver.t >= t_end * (1 - 1e-12)
            t0 = time.perf_counter()
            if solver.step_count % options.history_every == 0 or at_end:
                write_history(collective=False)  # (rank 0's errors: read with its clock, below)
            if frames.due(solver.t, solver.dt):
                series.write(solver.t, problem.parts())
            solver.timers.add("output", time.perf_counter() - t0)
            now = time.perf_counter()
            # a checkpoint by steps is known on every rank; by wall time one clock decides for
            # all ranks, read every CLOCK_EVERY steps (a broadcast every step waited for rank 0),
            # together with whether rank 0 could write its history rows
            due = bool(options.checkpoint_steps and solver.step_count % options.checkpoint_steps == 0)
            if solver.step_count % CLOCK_EVERY == 0 or at_end:
                clock, failed = comm.bcast((bool(now - last_ckpt > options.checkpoint_wall), history.error)
                                           if comm.rank == 0 else None, root=0)
                if failed is not None:
                    raise history.failure(failed)
                due = due or clock
            if due and not at_end:
                save()
                last_ckpt = time.perf_counter()
            if comm.rank == 0:
                done = solver.step_count - step0
                if not estimated and (done >= 20 or now - wall0 > 5.0):
                    estimated = True
                    left = (now - wall0) / done * (t_end - solver.t) / solver.dt
                    print(f"[hydrofrac] estimated wall time {_fmt_time(now - wall0 + left)} "
                          f"({_fmt_time(left)} to go) at {done} steps", flush=True)
                if now - last_progress > options.progress_wall:
                    eta = (now - wall0) / max(done, 1) * (t_end - solver.t) / solver.dt
                    rate = solver.num_dofs * solver.num_stages * done / (now - wall0)
                    print(f"[hydrofrac] step {solver.step_count}  t = {solver.t:.4e} s  "
                          f"({100 * solver.t / t_end:.0f}%)  {rate:.3g} DOF*stages/s  ETA {_fmt_time(eta)}",
                          flush=True)
                    last_progress = now
    except BlowUpError as err:
        t_bad = solver.t
        _restore_snapshot(problem, good)
        series.write(solver.t, problem.parts())
        save()
        msg = (f"{err}\n[hydrofrac] stopped. The last good state (t = {solver.t:.6g} s, before the blow-up at "
               f"t = {t_bad:.6g} s, with its energy budget) is in {series.pvd_path} and {ckpt.dir}")
        log(comm, msg)
        close()
        raise BlowUpError(msg) from None
    wall = time.perf_counter() - wall0
    compiling = compile_seconds() - compiled0
    loop["finished_at"] = t_end
    if before_last is None:
        save()
    else:
        snap, (prob, frame_list, done, mon, lp, geom) = before_last
        save(snap, (prob, frame_list, done, mon, dumps({**loads(lp), "finished_at": t_end}), geom))
    for p in retired:
        p.release()
    close()

    accuracy = dict(remesh.report()) if hasattr(remesh, "report") else {}
    for m in monitors:
        accuracy.update(m.accuracy(problem))
    summary = build_summary(problem, name, wall, loop["work"], solver.step_count - step0,
                            loop["remeshes"] if remesh is not None else None, accuracy,
                            {"paraview": str(series.pvd_path), "history": str(history_path),
                             "checkpoint": str(ckpt.dir),
                             **({"probes": str(out / "probes.csv")} if probes is not None else {})},
                            remeshes_timed=timed["remeshes"], unit_work=(timed["cell_stages"], timed["facet_stages"]),
                            compiling=compiling)
    write_summary(summary, out, comm)
    for m in monitors:
        line = m.report(accuracy)
        if line:
            log(comm, line)
    return summary


def _finished(comm, out: Path, ckpt: Checkpoint, t: float) -> Dict:
    """A restart of a run that already reached its end: report, touch nothing."""
    import json
    summary = None
    if comm.rank == 0 and (out / "summary.json").exists():
        summary = json.loads((out / "summary.json").read_text())
    summary = comm.bcast(summary, root=0)
    if summary is None:
        raise CheckpointError(f"the run in {out} reached its end (t = {t:.6g} s) but has no summary.json; "
                              "run it again without --restart, or with a larger --t-end to continue")
    log(comm, f"[hydrofrac] the run in {out} has already finished (t = {t:.6g} s); its output is left as it "
              "is. Give a larger --t-end to continue it")
    return summary
