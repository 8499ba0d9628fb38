"""Study: model no more than the scene needs (issue 7, study 3).

The regularised crack-intersection problem (``scenarios/intersection.py``) on meshes that
differ only in their size field: uniform (the crack size everywhere) against graded (fine at
the cracks, coarsening by the factor 1.5 per size to ``h_far``), at two crack sizes.  For
each: cells, DOFs, wall time of the run to 1 ms, and the error of two quantities of
interest against the finest run (graded, h = 3 cm at the cracks; the scenario's full size):

* the intersection time (when the growing crack connects to the natural fracture);
* the f_p-weighted loaded length of the natural fracture at 1 ms.

A third variant, lower p in the far field, is not supported (one p per mesh).

    mpirun -n 2 python -m hydrofrac.postprocess.study_mesh_grading [--out DIR]

Writes ``mesh_grading.csv`` into ``postprocess/results`` (``--out``).
"""
from __future__ import annotations

import time
from pathlib import Path

from mpi4py import MPI

from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import scenario, study_parser, timed_run

CASES = [  # name, h_crack, h_far
    ("graded, h = 3 cm (reference)", 0.03, 0.5),
    ("graded, h = 4.5 cm", 0.045, 0.6),
    ("graded, h = 6 cm (--quick)", 0.06, 0.8),
    ("uniform, h = 6 cm", 0.06, 0.06),
]
T_END = 1.0e-3


def run_case(h_crack, h_far):
    ix = scenario("intersection")
    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    problem = ix.setup(comm, regularized=True, h_crack=h_crack, h_far=h_far)
    solver = problem.solver
    setup = time.perf_counter() - t0
    mon = ix.IntersectionMonitor([c.tag for c in problem.network.cracks if c.kind == "natural"])
    wall = timed_run(problem, T_END, mon)
    acc = mon.accuracy(problem)
    return {"cells": solver.num_cells, "dofs": solver.num_dofs, "steps": solver.step_count, "dt": solver.dt,
            "setup_s": setup, "wall_s": wall, "intersection_time": acc["intersection_time"],
            "nf_loaded_length": acc["nf_loaded_length_final"]}


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    rows = []
    for name, hc, hf in CASES:
        r = {"case": name, "h_crack": hc, "h_far": hf, **run_case(hc, hf)}
        rows.append(r)
        if comm.rank == 0:
            print(f"[study] {name}: {r['cells']} cells, {r['dofs']} DOFs, {r['steps']} steps, wall {r['wall_s']:.1f} s, "
                  f"intersection {r['intersection_time'] * 1e6:.1f} µs, loaded length {r['nf_loaded_length']:.3f} m",
                  flush=True)
    ref = rows[0]
    for r in rows:
        r["intersection_time_error"] = r["intersection_time"] - ref["intersection_time"]
        r["loaded_length_error"] = r["nf_loaded_length"] - ref["nf_loaded_length"]
        r["ranks"] = comm.size
    if comm.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "mesh_grading.csv", rows)
        for r in rows:
            print(f"[study] {r['case']:30s} wall {r['wall_s']:7.1f} s  intersection error "
                  f"{r['intersection_time_error'] * 1e6:+6.1f} µs  loaded-length error {r['loaded_length_error']:+.3f} m",
                  flush=True)
    return rows


if __name__ == "__main__":
    main()
