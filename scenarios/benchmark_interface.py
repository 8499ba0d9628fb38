# # Benchmark: the crack interface's kernels
#
# Not a test: a measurement to run by hand (``make bench``), serially or on 2 ranks,
#
# ```
# python scenarios/benchmark_interface.py            # serial, ~1 minute
# python scenarios/benchmark_interface.py --quick    # seconds, a small plate
# ```
#
# On a plate of triangles with every fourth row of horizontal facets a crack (damage 0.5,
# the default contact and damage laws), under a smooth state, for p = 1, 2, 3 it measures
# (best of 5 repeats):
#
# 1. **one crack stage** (:meth:`hydrofrac.interface.Interface.stage_cells`' compiled pass:
#    traces, the four modes' Riemann solutions, the flux into the residual, the state rates),
#    in µs per crack facet·stage;
# 2. **ADER's Taylor values** of the cells next to crack facets
#    (:meth:`hydrofrac.matfree.MatrixFreeOperator.taylor_values` at the stage times), in µs per
#    cell, with the C kernels and with the numba ones side by side;
# 3. **ADER's whole interface step** (:meth:`hydrofrac.interface.Interface.ader_step`: the
#    Taylor values, the stages in one call, the states between them), in µs per crack facet·step;
# 4. **the end-of-step targets** (:meth:`hydrofrac.interface.Interface.evaluate`, what the
#    energy budget and the output read), in µs per crack facet.
#
# It writes ``interface_kernels_n<ranks>.csv`` to ``postprocess/results/`` (``--out``).
# docs/benchmarks.md, "The crack facets' pass, basis-major", gives what it measured.

# +
from __future__ import annotations

import time

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK, compat, native
from hydrofrac.interface import Crack, Interface, crack_facet_indices
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import benchmark_dir, benchmark_parser
from hydrofrac.solver import Solver

CRACK = 10
SIZES = {"quick": 24, "full": 72}


def log(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


def plate(comm, n):
    """The unit square in n x n squares of two triangles; every fourth inner row of horizontal
    facets is a crack (tag CRACK)."""
    mesh = compat.create_rectangle(comm, (0.0, 0.0), (1.0, 1.0), n, n)
    off, arr = compat.connectivity(mesh, 1, 0)
    v2g = compat.vertex_to_geometry(mesh)
    x = mesh.geometry.x[:, :2]
    a, b = x[v2g[arr[off[:-1]]]], x[v2g[arr[off[:-1] + 1]]]
    row = 0.5 * (a[:, 1] + b[:, 1]) * n
    horizontal = np.isclose(a[:, 1], b[:, 1]) & np.isclose(row, np.round(row))
    crack = np.flatnonzero(horizontal & (np.round(row).astype(int) % 4 == 2))
    return mesh, compat.meshtags(mesh, 1, crack, np.full(crack.size, CRACK))


def cracked_solver(comm, n, p):
    mesh, tags = plate(comm, n)
    cracks = [Crack(CRACK, damage=0.5)]
    solver = Solver(mesh, p, ROCK, facet_tags=tags, crack_facets=crack_facet_indices(mesh, tags, cracks),
                    scheme="ader")
    iface = Interface(solver, tags, cracks)
    solver.attach(iface)
    # a smooth state: a shear wave's velocity and stress (|v| ~ 0.1 m/s), so that the cracks
    # slip and open mildly, as in a run
    X = compat.dof_coordinates(solver.V)[:, :2]
    vals = np.zeros((X.shape[0], 5))
    vals[:, 0] = 0.1 * np.sin(2 * np.pi * X[:, 1])
    vals[:, 4] = -ROCK.Zs * vals[:, 0]
    with solver.x.localForm() as xl:
        xl.array[:] = vals.reshape(-1)
    iface.state = iface.state.copy()
    iface.evaluate(solver.x, 0.0, store=True)
    return solver, iface


def best(fn, repeats=5, calls=50):
    fn()
    out = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(calls):
            fn()
        out = min(out, (time.perf_counter() - t0) / calls)
    return out


def case(comm, n, p):
    """The four measurements at degree p on the n x n plate (this rank's facets and cells)."""
    row = {"ranks": comm.size, "p": p, "n": n}
    with native.using("numba"):
        numba_solver, numba_iface = cracked_solver(comm, n, p)
    solver, iface = cracked_solver(comm, n, p)
    mf = solver.matfree
    nf = iface.facets.size
    row["crack_facets"] = nf
    R = mf.R
    dt = solver.dt

    def taylor(X, Q, cells, taus):
        mf.taylor_values(X, Q, cells, taus, p)
    with solver.read_local(solver.x) as X:
        iface.stage_state = iface.state.copy()
        t_stage = best(lambda: iface._stage(X, 0.0, R, R.shape[0]))
        iface.ader_step(X, 0.0, dt, R, taylor)  # (its cells and Taylor arrays)
        cells, times, Q = iface._ader.cells, iface._ader.times, iface._ader.Q
        taus = [c * dt for c in times]
        t_taylor = best(lambda: mf.taylor_values(X, Q, cells, taus, p))
        t_step = best(lambda: iface.ader_step(X, 0.0, dt, R, taylor))
    R[:] = 0.0
    with numba_solver.read_local(numba_solver.x) as X:
        nmf = numba_solver.matfree
        Qn = np.zeros_like(Q)
        ncells = np.unique(numba_iface.cells.reshape(-1)).astype(np.int64)
        t_taylor_numba = best(lambda: nmf.taylor_values(X, Qn, ncells, taus, p))
    t_targets = best(lambda: iface.evaluate(solver.x, 0.0))
    per = max(nf, 1)
    row.update(crack_cells=int(cells.size), stage_us_per_facet=1e6 * t_stage / per,
               taylor_us_per_cell=1e6 * t_taylor / max(cells.size, 1),
               taylor_numba_us_per_cell=1e6 * t_taylor_numba / max(cells.size, 1),
               ader_step_us_per_facet=1e6 * t_step / per, targets_us_per_facet=1e6 * t_targets / per,
               interface_kernels=mf.kernels)
    return row


def main(argv=None):
    args = benchmark_parser("Speed of the crack interface's kernels (per facet, per cell)").parse_args(argv)
    comm = MPI.COMM_WORLD
    out = benchmark_dir(comm, args)
    n = SIZES["quick" if args.quick else "full"]
    rows = []
    for p in (1, 2, 3):
        r = case(comm, n, p)
        rows.append(r)
        log(comm, f"[bench] p={p} {r['crack_facets']} crack facets, {r['crack_cells']} crack cells (rank 0): "
                  f"a stage {r['stage_us_per_facet']:.3f} us/facet; ADER's Taylor values {r['taylor_us_per_cell']:.3f} "
                  f"us/cell ({r['interface_kernels']}; numba {r['taylor_numba_us_per_cell']:.3f}, "
                  f"{r['taylor_numba_us_per_cell'] / r['taylor_us_per_cell']:.1f}x); ADER's interface step "
                  f"{r['ader_step_us_per_facet']:.3f} us/facet; the end-of-step targets "
                  f"{r['targets_us_per_facet']:.3f} us/facet")
    if comm.rank == 0:
        path = out / f"interface_kernels_n{comm.size}.csv"
        write_csv(path, rows)
        print(f"[bench] wrote {path}", flush=True)


if __name__ == "__main__":
    main()
