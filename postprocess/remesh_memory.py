"""Peak memory per rank during a remesh of a large block (docs/benchmarks.md, "Remeshing").

A 2 m x 2 m block meshed uniformly at ``--h`` (0.0068 m: about 200k cells), p = 2, with one
debonded crack whose tip is made to advance once (onset 0, checked at the first step), so
that the driver remeshes once: the whole block (Gmsh on rank 0, distribution), or with
``--remesh patch`` a local patch of the distributed mesh (meshes/patch.py); then a new solver,
the field and interface transfer.  Prints, per rank, the resident memory after the first
build, the peak (high-water mark) before the remesh, and the peak and resident memory after.

    mpirun -n 2 python -m hydrofrac.postprocess.remesh_memory [--h 0.0068] [--degree 2] [--remesh patch]
"""
from __future__ import annotations

import argparse
import json
import resource
import time

import numpy as np
from mpi4py import MPI

from hydrofrac import compat
from hydrofrac.block import block_builder
from hydrofrac.growth import GrowthDriver, GrowthParams, Tip
from hydrofrac.interface import Crack
from hydrofrac.meshes.fractures import PATH, Domain, Fracture


def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * resource.getpagesize() / 2**20


def peak_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=0.0068)
    parser.add_argument("--degree", type=int, default=2)
    parser.add_argument("--remesh", choices=("full", "patch"), default="full")
    parser.add_argument("--patch-radius", type=float, default=0.05, help="[m], with --remesh patch")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    dom = Domain(half_width=1.0, half_height=1.0, wellbore_radius=0.0, h_crack=args.h, h_far=args.h, grading=0.5)
    build = block_builder(comm, dom, [Fracture((-0.2, 0.0), 0.0, 0.4, friction=0.0)], [Crack(0, damage=1.0)],
                          sigma0=[[0.0, 0.0], [0.0, 1e6]], degree=args.degree,
                          patch_radius=args.patch_radius if args.remesh == "patch" else None)
    t0 = time.perf_counter()
    drv = GrowthDriver(build, [Tip(np.array([0.0, 0.0]), np.array([1.0, 0.0]))], GrowthParams(r=4 * args.h),
                       da=2 * args.h, threshold=0.0, tags=[PATH], check_every=1)
    t_build = time.perf_counter() - t0
    problem = drv.problem
    cells = comm.allreduce(compat.num_cells_local(problem.solver.mesh), op=MPI.SUM)
    problem.solver.step()
    before = (rss_mb(), peak_mb())
    t0 = time.perf_counter()
    new = drv(problem)
    t_remesh = time.perf_counter() - t0
    assert new is not None, "the tip did not advance"
    after = (rss_mb(), peak_mb())
    fm = new.fracture_mesh
    region = comm.bcast(fm.region_cells, root=0)
    held = comm.allgather(len(fm.arrays.cells) if fm.remesh == "patch" else
                          (0 if fm.arrays is None else len(fm.arrays.tris)))
    rows = comm.gather({"rank": comm.rank, "rss_before_mb": before[0], "peak_before_mb": before[1],
                        "rss_after_mb": after[0], "peak_after_mb": after[1]}, root=0)
    if comm.rank == 0:
        print(json.dumps({"ranks": comm.size, "cells": cells, "degree": args.degree, "remesh": fm.remesh,
                          "patch_cells": fm.patch_cells, "region_cells_on_rank0": region, "mesh_input_cells_per_rank": held,
                          "dofs": cells * (args.degree + 1) * (args.degree + 2) // 2 * 5,
                          "build_s": t_build, "remesh_s": t_remesh, "per_rank": rows}, indent=1))


if __name__ == "__main__":
    main()
