"""Pieces shared by the study scripts (``study_*.py``): the common command line, a timed run
of a problem, work-precision helpers and the chart finishing."""
from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac.loader import scenario  # noqa: F401  (the studies load scenarios through it)


def study_parser(doc):
    """``--quick`` and ``--out`` (default ``postprocess/results``), described by the module's
    first docstring line."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer and smaller cases (seconds)")
    parser.add_argument("--out", default="postprocess/results")
    return parser


def benchmark_parser(description):
    """A benchmark script's ``--quick`` (small sizes) and ``--out`` (default
    ``postprocess/results``, or ``results/benchmark_quick`` with ``--quick``: a quick run does not
    overwrite the measured files); :func:`benchmark_dir` makes the folder."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--quick", action="store_true", help="small sizes (seconds)")
    parser.add_argument("--out", default=None,
                        help="output folder (default postprocess/results, or results/benchmark_quick with --quick)")
    return parser


def benchmark_dir(comm, args):
    """The output folder of a :func:`benchmark_parser` run (made on rank 0)."""
    out = Path(args.out or ("results/benchmark_quick" if args.quick else "postprocess/results"))
    if comm.rank == 0:
        out.mkdir(parents=True, exist_ok=True)
    return out


def cases(args, quick, full):
    """(key, N) for every size of a study: ``quick`` with ``--quick``, else ``full``
    (both ``{key: [N, ...]}``)."""
    return [(key, N) for key, Ns in (quick if args.quick else full).items() for N in Ns]


def say(comm, text):
    """Print ``[study] text`` on rank 0."""
    if comm.rank == 0:
        print(f"[study] {text}", flush=True)


def results_dir(comm, args, rows):
    """On rank 0 the output folder (made), every row tagged with the rank count; None on the
    other ranks (they write nothing)."""
    if comm.rank != 0:
        return None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for r in rows:
        r["ranks"] = comm.size
    return out


def timed_run(problem, t_end, monitor=None):
    """Step ``problem`` (a :class:`~hydrofrac.problem.Problem` or a bare solver) to ``t_end``
    as :func:`hydrofrac.run.run` does (energy budget, blow-up check, the problem's own
    updates), without output, calling ``monitor(problem)`` after each step; returns the wall
    time (max over ranks) [s]."""
    from hydrofrac.problem import Problem
    problem = problem if isinstance(problem, Problem) else Problem(problem)
    solver, comm = problem.solver, problem.comm
    comm.barrier()
    t0 = time.perf_counter()
    solver.update_energy()
    while solver.t < t_end * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        solver.check_stability()
        problem.after_step()
        if monitor is not None:
            monitor(problem)
    comm.barrier()
    return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)


def wall_at(rows, target, key, value="wall_s"):
    """Smallest wall time (or other cost ``row[value]``: flops) at which any method of ``rows``
    reaches error ``row[key] <= target``, interpolating log(cost) against log(error) between
    consecutive sizes of a method (by ``row["dofs"]``); inf if none does."""
    best = math.inf
    for m in sorted({r["method"] for r in rows}):
        rs = sorted([r for r in rows if r["method"] == m], key=lambda r: r["dofs"])
        for a, b in zip(rs, rs[1:]):
            ea, eb = max(a[key], 1e-300), max(b[key], 1e-300)
            if (ea - target) * (eb - target) <= 0 and ea != eb:
                s = (math.log(target) - math.log(ea)) / (math.log(eb) - math.log(ea))
                best = min(best, math.exp(math.log(a[value]) + s * (math.log(b[value]) - math.log(a[value]))))
        for r in rs:
            if r[key] <= target:
                best = min(best, r[value])
    return best


def log_axes(*axes):
    """Grid on both scales and a legend, as every study chart has them."""
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)


def save_figure(fig, png):
    """Lay out, write and close a study chart."""
    import matplotlib.pyplot as plt
    fig.tight_layout()
    fig.savefig(png)
    plt.close(fig)


def plane_wave_solver(comm, p, N, material, state, travel, scheme="rk4", cfl=None, point=None):
    """DG solver on the unit square (``N`` x ``N`` cells) with the exact plane wave
    ``state(x, t)`` as initial state and as outer boundary state (``point``: the same as a
    compiled point function, :class:`~hydrofrac.boundary.OuterState`), and a time step that
    ends exactly when the wave has travelled ``travel`` (at c_d), at the CFL constant ``cfl``
    of ``scheme`` (None: its documented value).  Returns (solver, steps)."""
    from hydrofrac import compat
    from hydrofrac.boundary import OuterState
    from hydrofrac.solver import Solver
    mesh = compat.create_rectangle(comm, (0.0, 0.0), (1.0, 1.0), N, N)
    facets = compat.locate_boundary_facets(mesh, lambda x: np.full(x.shape[1], True))
    tags = compat.meshtags(mesh, 1, facets, np.full(facets.size, 1))
    solver = Solver(mesh, p, material, facet_tags=tags, bcs=[OuterState(1, state, point)], scheme=scheme, cfl=cfl)
    solver.set_initial_state(lambda x: state(x, 0.0))
    t_end = travel / material.cd
    steps = int(math.ceil(t_end / solver.dt - 1e-9))
    solver.dt = t_end / steps
    return solver, steps
