# # Benchmark: speed and accuracy of the bulk DG solver
#
# Not a test: a measurement to run by hand (``make bench``) on 1 and 2 ranks,
#
# ```
# python scenarios/benchmark_bulk.py               # serial, ~5 minutes
# mpirun -n 2 python scenarios/benchmark_bulk.py   # two ranks
# python scenarios/benchmark_bulk.py --quick       # seconds, small meshes
# ```
#
# It measures three things and writes them to ``postprocess/results/`` (``--out``):
#
# 1. **Throughput** of the bulk time step, in DOF·stages per second, for p = 1, 2, 3
#    on three structured meshes of the unit square each (the largest has ~0.4-0.55
#    million DOFs), for both bulk operators side by side on the same mesh: the
#    matrix-free kernels (default) and the assembled BAIJ matrix; also the operator
#    application alone; and the matrix-free ADER step (:data:`hydrofrac.solver.ADER`) in
#    unknown·steps/s against rk4's.  File ``bulk_throughput_n<ranks>.csv``.
# 2. **Memory bandwidth** of the machine: a NumPy copy of a 128 MiB array on every
#    rank at once, counted as bytes read + bytes written per second (the
#    write-allocate read of the destination is not counted, so this is a
#    conservative ``STREAM copy``-like figure).  The throughput is reported as a
#    fraction of the rate this bandwidth allows under the byte model below.
# 3. **Work–precision**: the relative error of a plane P wave (exact solution
#    imposed as the outer state on the whole boundary) against the wall time of
#    the time loop, over p and h.  Files ``work_precision_n<ranks>.csv`` and ``.png``.
#
# ## Byte model of one stage (per DOF)
#
# One RK stage of :meth:`hydrofrac.solver.Solver.step` does, per DOF, with 8-byte
# doubles and every vector entry counted once per pass:
#
# * ``A.mult(y, k)``: the stored entries of the BAIJ operator ``A = M⁻¹K`` (8 bytes
#   each, *including* the structural zeros DOLFINx's sparsity pattern keeps:
#   ~59, 118, 195 per row for p = 1, 2, 3), one 4-byte column index per 5×5 block,
#   the row pointers, plus reading ``y`` and writing ``k`` (16 bytes);
# * the RK vector updates as coded: a stage vector with one earlier stage in it,
#   ``y = x + c k_j`` (all of RK4's but the first), in one pass (24 bytes); otherwise the
#   copy ``y = x`` (16 bytes) and ``y += Σ a_ij k_j`` over the nonzero a_ij
#   (``VecMAXPY``: (terms + 2)·8 bytes); and the final ``x += Σ b_j k_j`` shared by
#   the s stages ((s + 2)·8/s bytes).  For RK4 these average 34 bytes per DOF·stage.
#
# So bytes/(DOF·stage) = (8·nnz + 4·nblocks + 4·(block rows + 1))/n + 16 + 34 for
# RK4; for p = 1 about 540 bytes, dominated by the matrix.
#
# The matrix-free operator (:mod:`hydrofrac.matfree`) instead reads ``y`` once and
# writes ``k`` once (16 bytes), round-trips the cell residual array (zero, accumulate,
# read: 32 bytes) and reads its per-cell and per-facet data once (inverse Jacobian,
# 1/|det J|, a material index, and the dofmap only if the DG numbering is not cell by
# cell; the facets' cells, node-list codes, normal, length and both cells' impedances),
# counted from the arrays' sizes: ~10 bytes per DOF at p = 1.
# The boundary facets' operator touches the boundary cells' rows only (not counted).
# Re-reads of ``y`` by the up to three facets of a cell are assumed to hit the cache.
# The bound is ``bandwidth / bytes`` DOF·stages/s.

# +
from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK, compat, native
from hydrofrac.postprocess.roofline import (ader_model, bytes_per_dof_stage, copy_bandwidth, flops_per_dof_stage,
                                            peak_flops)
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import (benchmark_dir, benchmark_parser, log_axes, plane_wave_solver,
                                                 save_figure)
from hydrofrac.postprocess.study_work_precision import TRAVEL, state_pt
from hydrofrac.postprocess.study_work_precision import state as plane_wave
from hydrofrac.solver import Solver, default_cfl
# -

# ## Sizes
#
# (p, N) with an N x N square of right-diagonal triangles (2N² cells,
# 5(p+1)(p+2)/2 DOFs per cell).

THROUGHPUT = {1: (32, 64, 128), 2: (24, 48, 96), 3: (20, 40, 64)}
WORK_PRECISION = {1: (8, 16, 32, 64), 2: (8, 16, 32), 3: (8, 16, 32)}
QUICK_THROUGHPUT = {1: (8, 16, 24), 2: (6, 12, 18), 3: (4, 8, 12)}
QUICK_WORK_PRECISION = {1: (4, 8, 16), 2: (4, 8), 3: (4, 8)}
MIN_WALL = 1.0  # seconds of stepping per throughput case


def log(comm, *args):
    if comm.rank == 0:
        print(*args, flush=True)


# ## Throughput of the time step

def unit_square(comm, N):
    return compat.create_rectangle(comm, (0.0, 0.0), (1.0, 1.0), N, N)


def timed(comm, fn, count):
    comm.barrier()
    t0 = time.perf_counter()
    for _ in range(count):
        fn()
    comm.barrier()
    return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)


def throughput_case(comm, p, N, bandwidth, operator, mesh, peak=None, scheme="rk4"):
    t0 = time.perf_counter()
    solver = Solver(mesh, p, ROCK, operator=operator, scheme=scheme)
    setup = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
    x = solver.x.duplicate()
    x.setRandom()
    x.copy(solver.x)
    y = x.duplicate()
    n, s = solver.num_dofs, solver.num_stages
    # calibrate the number of steps on one step, then time
    one = timed(comm, solver.step, 1)
    steps = max(3, int(math.ceil(MIN_WALL / max(one, 1e-9))))
    steps = comm.bcast(steps, root=0)
    wall = timed(comm, solver.step, steps)
    mults = max(3, steps * s)
    wall_mult = timed(comm, lambda: solver.rhs(x, 0.0, y), mults)
    rate = n * s * steps / wall
    if scheme == "ader":  # (its own flop and byte model per step: ader_model)
        for v in (x, y):
            v.destroy()
        flops, nbytes = ader_model(solver)
        per_step = n * steps / wall
        row = {"operator": f"{operator} ader", "p": p, "N": N, "cells": solver.num_cells, "dofs": n,
               "ranks": comm.size, "setup_s": setup, "steps": steps, "stages": s, "wall_s": wall,
               "dof_stages_per_s": rate, "dof_stages_per_s_per_rank": rate / comm.size,
               "unknown_steps_per_s_per_rank": per_step / comm.size,
               "bytes_per_dof_step": nbytes, "bandwidth_GBs": bandwidth / 1e9,
               "fraction_of_bound": per_step * nbytes / bandwidth, "flops_per_dof_step": flops}
        if peak:
            row.update({"peak_GFlops_per_core": peak / 1e9,
                        "fraction_of_peak_flops": per_step / comm.size * flops / peak})
        return row
    op_bytes, rk_bytes = bytes_per_dof_stage(solver)
    row = {
        "operator": operator, "p": p, "N": N, "cells": solver.num_cells, "dofs": n, "ranks": comm.size, "setup_s": setup,
        "steps": steps, "stages": s, "wall_s": wall, "dof_stages_per_s": rate, "dof_stages_per_s_per_rank": rate / comm.size,
        "mult_dofs_per_s": n * mults / wall_mult,
        "bytes_per_dof_stage": op_bytes + rk_bytes, "operator_bytes_per_dof": op_bytes,
        "bandwidth_GBs": bandwidth / 1e9,
        "fraction_of_bound": rate * (op_bytes + rk_bytes) / bandwidth,
        "mult_fraction_of_bound": n * mults / wall_mult * op_bytes / bandwidth,
        "unknown_steps_per_s_per_rank": n * steps / wall / comm.size,
    }
    flops = flops_per_dof_stage(solver)
    if flops is not None and peak:  # one core's peak per rank
        row.update({"flops_per_dof_stage": flops, "peak_GFlops_per_core": peak / 1e9,
                    "fraction_of_peak_flops": rate / comm.size * flops / peak})
    for v in (x, y):
        v.destroy()
    return row


# ## Work–precision: a plane P wave
#
# A Gaussian pulse of width 0.12 m travelling at c_d in the direction at 0.3 rad
# from the x axis, centred in the unit square at t = 0, run for 0.2 m of travel.
# The exact state is imposed as the outer state on every boundary facet, so the
# only error is the discretisation's.  The error is measured in the mass-matrix
# (energy) norm, ρ|v|² + σ:C⁻¹σ, of the difference between the DG solution and
# the nodal interpolant of the exact one, relative to the norm of the latter.

# the plane P wave of the work-precision study (exact state and its compiled point form)


def energy_norm(solver, values):
    """sqrt(u^T M u) of the owned nodal values (own, 5)."""
    u = solver.x.duplicate()
    u.array[:] = values.reshape(-1)
    Mu = u.duplicate()
    solver.M.mult(u, Mu)
    val = math.sqrt(max(u.dot(Mu), 0.0))
    u.destroy()
    Mu.destroy()
    return val


def work_precision_case(comm, p, N):
    solver, steps = plane_wave_solver(comm, p, N, ROCK, plane_wave, TRAVEL, point=state_pt)
    wall = timed(comm, solver.step, steps)
    own = compat.dof_counts(solver.V)[0]
    exact = plane_wave(compat.dof_coordinates(solver.V)[:own].T, solver.t).T
    error = energy_norm(solver, solver.local_array() - exact) / energy_norm(solver, exact)
    return {"p": p, "N": N, "h": 1.0 / N, "dofs": solver.num_dofs, "ranks": comm.size, "steps": steps,
            "wall_s": wall, "rel_error": error}


# ## Output

def plot_work_precision(rows, png: Path, ranks: int):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(6, 4.2), dpi=100)
    for p in sorted({r["p"] for r in rows}):
        rs = [r for r in rows if r["p"] == p]
        ax.loglog([r["wall_s"] for r in rs], [r["rel_error"] for r in rs], "o-", label=f"p = {p}")
        for r in rs:
            ax.annotate(f"N={r['N']}", (r["wall_s"], r["rel_error"]), textcoords="offset points", xytext=(4, 3),
                        fontsize=7)
    ax.set_xlabel("wall time of the time loop [s]")
    ax.set_ylabel("relative error (energy norm)")
    ax.set_title(f"Plane P wave, DG P_p + RK4, {ranks} rank(s)", fontsize=10)
    log_axes(ax)
    save_figure(fig, png)


def rate_table(rows):
    """Markdown table of the throughput rows."""
    lines = ["| operator | p | N | DOFs | ranks | DOF·stages/s | per rank | unknown·steps/s per rank | "
             "bytes/DOF·stage | bandwidth fraction | operator-only fraction | flops/DOF·stage | "
             "peak-flop fraction |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        fl = (f"{r['flops_per_dof_stage']:.0f} | {r['fraction_of_peak_flops']:.3f}" if "flops_per_dof_stage" in r
              else "— | —")
        by = (f"{r['bytes_per_dof_stage']:.0f} | {r['fraction_of_bound']:.2f} | {r['mult_fraction_of_bound']:.2f}"
              if "bytes_per_dof_stage" in r else "— | — | —")
        lines.append(f"| {r['operator']} | {r['p']} | {r['N']} | {r['dofs']} | {r['ranks']} | "
                     f"{r['dof_stages_per_s']:.3g} | "
                     f"{r['dof_stages_per_s_per_rank']:.3g} | {r['unknown_steps_per_s_per_rank']:.3g} | {by} | {fl} |")
    return "\n".join(lines)


def slopes(rows):
    """Fitted convergence slope of the error against h per degree."""
    out = {}
    for p in sorted({r["p"] for r in rows}):
        rs = [r for r in rows if r["p"] == p]
        if len(rs) >= 2:
            out[p] = float(np.polyfit(np.log([r["h"] for r in rs]), np.log([r["rel_error"] for r in rs]), 1)[0])
    return out


def main(argv=None):
    parser = benchmark_parser("Throughput and work-precision benchmark of the bulk DG solver")
    parser.add_argument("--skip-work-precision", action="store_true", help="throughput and bandwidth only")
    args = parser.parse_args(argv)
    comm = MPI.COMM_WORLD
    out = benchmark_dir(comm, args)
    tp_sizes = QUICK_THROUGHPUT if args.quick else THROUGHPUT
    wp_sizes = QUICK_WORK_PRECISION if args.quick else WORK_PRECISION

    bandwidth = copy_bandwidth(comm)
    peak = comm.bcast(peak_flops() if comm.rank == 0 else None, root=0)
    log(comm, f"[bench] {comm.size} rank(s); memory copy bandwidth {bandwidth / 1e9:.2f} GB/s "
              f"(read + write, all ranks); one core's multiply-add peak {peak / 1e9:.1f} GFlop/s")
    rows = []
    for p, Ns in tp_sizes.items():
        for N in Ns:
            mesh = unit_square(comm, N)
            pair = {}
            for operator in ("matfree", "assembled"):
                r = throughput_case(comm, p, N, bandwidth, operator, mesh, peak)
                rows.append(r)
                pair[operator] = r["dof_stages_per_s"]
                log(comm, f"[bench] {operator:9s} p={p} N={N:4d} {r['dofs']:8d} DOFs: step "
                          f"{r['dof_stages_per_s']:.3g} DOF*stages/s ({r['fraction_of_bound']:.2f} of the bound at "
                          f"{r['bytes_per_dof_stage']:.0f} B), operator alone {r['mult_dofs_per_s']:.3g} DOF/s "
                          f"({r['mult_fraction_of_bound']:.2f}), setup {r['setup_s']:.1f} s"
                          + (f"; {r['flops_per_dof_stage']:.0f} flop/DOF*stage, {r['fraction_of_peak_flops']:.3f} "
                             "of the peak" if "flops_per_dof_stage" in r else ""))
            log(comm, f"[bench]           matrix-free / assembled step rate: {pair['matfree'] / pair['assembled']:.2f}")
            # the same matrix-free step with the numba kernels alone (the C kernels' gain, side by side)
            with native.using("numba"):
                r = throughput_case(comm, p, N, bandwidth, "matfree", mesh, peak)
            r["operator"] = "matfree numba"
            rows.append(r)
            log(comm, f"[bench]           C kernels / numba kernels step rate: "
                      f"{pair['matfree'] / r['dof_stages_per_s']:.2f} (numba: {r['dof_stages_per_s']:.3g} DOF*stages/s"
                      + (f", {r['fraction_of_peak_flops']:.3f} of the peak)" if "fraction_of_peak_flops" in r else ")"))
            r = throughput_case(comm, p, N, bandwidth, "matfree", mesh, peak, scheme="ader")
            rows.append(r)
            rk4 = next(q for q in rows if q["operator"] == "matfree" and q["p"] == p and q["N"] == N)
            log(comm, f"[bench] ADER      p={p} N={N:4d}: {r['unknown_steps_per_s_per_rank']:.3g} unknown*steps/s per "
                      f"rank, {r['unknown_steps_per_s_per_rank'] / rk4['unknown_steps_per_s_per_rank']:.2f}x rk4's; "
                      f"its step is {default_cfl('ader', p) / default_cfl('rk4', p):.2f}x as long; "
                      f"{r['fraction_of_bound']:.2f} of the bound at {r['bytes_per_dof_step']:.0f} B, "
                      f"{r['flops_per_dof_step']:.0f} flop/DOF*step, {r['fraction_of_peak_flops']:.3f} of the peak")
    if comm.rank == 0:
        write_csv(out / f"bulk_throughput_n{comm.size}.csv", rows)
        print(rate_table(rows), flush=True)

    if not args.skip_work_precision:
        wp = []
        for p, Ns in wp_sizes.items():
            for N in Ns:
                r = work_precision_case(comm, p, N)
                wp.append(r)
                log(comm, f"[bench] plane wave p={p} N={N:3d} {r['dofs']:7d} DOFs {r['steps']:4d} steps: "
                          f"error {r['rel_error']:.3e}, wall {r['wall_s']:.2f} s")
        if comm.rank == 0:
            write_csv(out / f"work_precision_n{comm.size}.csv", wp)
            png = out / f"work_precision_n{comm.size}.png"
            plot_work_precision(wp, png, comm.size)
            print("[bench] convergence slopes (error vs h): "
                  + ", ".join(f"p={p}: {s:.2f}" for p, s in slopes(wp).items()), flush=True)
            print(f"[bench] wrote {out}/bulk_throughput_n{comm.size}.csv, work_precision_n{comm.size}.csv, "
                  f"{png.name}", flush=True)


if __name__ == "__main__":
    main()
