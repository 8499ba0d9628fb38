"""Study: what local time stepping could gain on the scenarios' graded meshes (issue 7).

One global explicit step is set by the smallest cell: dt = CFL h_min / ((2p + 1) c_d).  A
local-time-stepping (LTS) scheme would advance each cell with its own stable step.  This
study measures, on the meshes the fracture scenarios actually run on, how much work that
could save at best, before anyone builds it:

* per cell, the stable step dt_c = CFL (h/c_d)_c / (2p + 1), with the same inradius-based
  h/c_d as the solver's global step;
* **ideal per-cell LTS**: the work relative to global stepping, Σ_c dt_min/dt_c / N_cells
  (every cell at its own step, no overhead);
* **2^k levels** (the usual multirate / LTS-RK construction): cell c steps with
  dt_min 2^k_c, k_c = floor(log2(dt_c/dt_min)) capped at ``--levels`` - 1; work
  Σ_c 2^-k_c / N_cells;
* the share of cells (and of DOFs) on the finest level.

The speed-up is an upper bound: LTS adds interface work between levels, and the crack
facets, where the cells are smallest, carry the expensive interface kernel.

    python -m hydrofrac.postprocess.study_local_time_stepping [--quick] [--out DIR]

Writes ``local_time_stepping.csv`` into ``postprocess/results`` (``--out``).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.cost_model import lts_gain
from hydrofrac.postprocess.study_common import scenario, study_parser


def cell_steps(solver):
    """Stable step of every owned cell, gathered on all ranks [s]."""
    from hydrofrac import compat
    nloc = compat.num_cells_local(solver.mesh)
    h_over_c = (solver.geometry.inradius * 2.0 / solver.cd_cell)[:nloc]
    dt = solver.cfl * h_over_c / (2 * solver.degree + 1)
    return np.concatenate(solver.comm.allgather(dt))


def scenes(quick):
    """(name, solver) of the fracture scenarios' meshes (pre-meshed paths: the geometry of a
    free-growth run before and after growth is graded the same way around the cracks)."""
    ix = scenario("intersection")
    rf = scenario("refracture")
    yield "intersection, --quick", ix.setup(quick=True, degree=2).solver
    if not quick:
        yield "intersection, full size", ix.setup(quick=False, degree=2).solver
        yield "refracture, full size", rf.setup(quick=False, degree=2).solver
    yield "refracture, --quick (p = 1)", rf.setup(quick=True, degree=1).solver


def main(argv=None):
    parser = study_parser(__doc__)
    parser.add_argument("--levels", type=int, default=6, help="number of 2^k time-step levels (default 6)")
    args = parser.parse_args(argv)
    if args.levels < 1:
        parser.error(f"--levels must be >= 1; got {args.levels}")
    comm = MPI.COMM_WORLD
    rows = []
    for name, solver in scenes(args.quick):
        dtc = cell_steps(solver)
        g = lts_gain(dtc, solver.dt, args.levels)
        rows.append({"mesh": name, "cells": dtc.size, "p": solver.degree, "dt_global": solver.dt, **g})
        if comm.rank == 0:
            print(f"[study] {name}: {dtc.size} cells, dt {solver.dt:.3g} s; cells' stable steps up to "
                  f"{g['dt_max_over_min']:.1f}x it; ideal LTS {g['speedup_ideal']:.2f}x, {g['levels_used']} "
                  f"2^k levels {g['speedup_levels']:.2f}x; {100 * g['finest_level_share']:.0f} % of the cells "
                  f"on the finest level", flush=True)
    if comm.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "local_time_stepping.csv", rows)
        print(f"[study] wrote {out / 'local_time_stepping.csv'}")


if __name__ == "__main__":
    main()
