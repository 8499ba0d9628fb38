"""The roofline's models and ceilings, shared by ``scenarios/benchmark_bulk.py`` (the bulk
step's fractions of the machine) and ``study_peer_devito`` (the flops each code spends for an
error): one core's multiply-add peak, the copy bandwidth, and the flop and byte counts per
DOF of the matrix-free stage and ADER step, counted from the kernels' loops
(docs/benchmarks.md, "Roofline").
"""
from __future__ import annotations

import math
import time

import numpy as np
from mpi4py import MPI

from hydrofrac.element import dimension as dim
from hydrofrac.solver import LOW_STORAGE, TABLEAUX, Solver


# ## Memory bandwidth

def copy_bandwidth(comm, mib=128, repeats=7):
    """Aggregate bytes (read + written) per second of ``np.copyto`` on all ranks at once."""
    n = mib * 2 ** 20 // 8
    src = np.random.default_rng(comm.rank).random(n)
    dst = np.empty_like(src)
    np.copyto(dst, src)
    best = math.inf
    for _ in range(repeats):
        comm.barrier()
        t0 = time.perf_counter()
        np.copyto(dst, src)
        comm.barrier()
        best = min(best, time.perf_counter() - t0)
    return comm.size * 2 * src.nbytes / best


# ## Peak floating-point rate of one core
#
# The roofline's compute ceiling: 64 independent multiply-add chains a = a b + c, compiled by
# numba with FMA contraction (LLVM packs them into vector FMAs: 512-bit on this machine),
# long enough (2.6 GFlop) to time.  NumPy's BLAS here is the reference BLAS (4.6 GFlop/s in
# DGEMM), not a peak.

def _fma_chains_source(k=64):
    names = [f"a{i}" for i in range(k)]
    lines = ["def chains(n, b, c):", "    " + ", ".join(names) + " = " + ", ".join(f"{1 + i * 1e-3}" for i in range(k)),
             "    for _ in range(n):"] + [f"        {a} = {a} * b + c" for a in names]
    return "\n".join(lines + ["    return " + " + ".join(names)]) + "\n", k


def peak_flops(n=20_000_000, repeats=3):
    """One core's multiply-add rate [flop/s] (the chains above)."""
    import numba
    src, k = _fma_chains_source()
    ns = {}
    exec(src, ns)  # (generated: 64 chains written out, so that each is a register)
    chains = numba.njit(fastmath={"contract"})(ns["chains"])
    chains(10, 0.999, 1e-3)
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        chains(n, 0.999999, 1e-7)
        best = min(best, time.perf_counter() - t0)
    return 2.0 * k * n / best


# ## Flop model of one stage (per DOF), matrix-free
#
# Counted from the kernels' loops (a multiply-add = 2 flops), per owned cell with nb basis
# functions and per facet with nk = p + 1 nodes:
#
# * volume: both reference derivatives 2·(2 rows·nb · 5), the inverse Jacobian's combinations
#   rows · 16 (rows = nb, or 1 at P1, where the rows of S_r are equal: `matfree._kernels`), adding the cell residual nb · 10, the reference inverse mass 2 nb² · 5, the
#   material block nb · 20;
# * an interior facet: per node the jumps and their rotation (28), two bonded solutions (16),
#   the rotation back for both sides (32); per side the facet mass matrix 2 nk² · 5;
# * a boundary facet: per node the trace rotation (12), the two components (8), the rotation
#   back (16); the facet mass matrix 2 nk² · 5;
# * the RK4 vector updates: 2 flops per DOF·stage for y = x + c k and 2 for the final sum.

def flops_per_dof_stage(solver: Solver):
    """Flops per DOF·stage of the matrix-free step (the model above); None when assembled."""
    mf = solver.matfree
    if mf is None:
        return None
    nb, nk = mf.dofs.shape[1], mf.fnodes.shape[1]
    rows = 1 if nb == 3 else nb
    cell = 2 * (2 * rows * nb * 5) + rows * 16 + nb * 10 + 2 * nb * nb * 5 + nb * 20
    facet = nk * (28 + 16 + 32) + 2 * (2 * nk * nk * 5)
    bfacet = nk * (12 + 8 + 16) + 2 * nk * nk * 5
    total = mf.nowned * cell + mf.fcells.shape[0] * facet + mf.bcells.shape[0] * bfacet
    return solver.comm.allreduce(total, op=MPI.SUM) / solver.num_dofs + 4.0


# ## Flop and byte model of one ADER step (per DOF), matrix-free
#
# One compiled pass per step over the cells (corrector and next predictor,
# `matfree.ader_corrector`) plus the interior and boundary facet fluxes of the predictor's
# integral I, counted as above:
#
# * per cell: the corrector's volume terms, residual and inverse mass (the volume line above),
#   x += that (nb · 5), then the predictor: dt x (nb · 5) and p times the local derivative
#   (the reference derivatives and inverse-Jacobian combinations as above, the material block
#   nb · 20) with its Taylor term (2 nb · 5);
# * with the C kernels the predictor works in the degrees its terms have
#   (`matfree.taylor_chain`): the m-th derivative reads n_{p-m+1} rows and writes n_{p-m}
#   (n_k = dim P_k; the first reads the nb nodes), 2·(2·n_{p-m}·n_{p-m+1}·5), with the
#   combinations n_{p-m} · 16 and the material block n_{p-m} · 20, and its Taylor term is
#   interpolated at the nodes and added, 2 nb·n_{p-m}·5 + 2 nb · 5;
# * the facets: as in a stage.
#
# Bytes per DOF: the facets read I (8) and accumulate into the cell residual (read and write,
# 16); the pass reads I and the residual (16), clears the residual (8), reads and writes x
# (16) and writes the new I (8); plus the same per-cell and per-facet data as a stage.

def ader_model(solver: Solver):
    """(flops, bytes) per DOF·step of the matrix-free ADER step (the model above)."""
    mf = solver.matfree
    nb, nk, p = mf.dofs.shape[1], mf.fnodes.shape[1], solver.degree
    rows = 1 if nb == 3 else nb
    derivative = 2 * (2 * rows * nb * 5) + rows * 16
    cell = derivative + nb * 10 + 2 * nb * nb * 5 + nb * 20 + nb * 5 + nb * 5
    if mf.kernels == "c":
        for m in range(1, p + 1):
            n_in, n_out = (nb if m == 1 else dim(p - m + 1)), dim(p - m)
            cell += 2 * (2 * n_out * n_in * 5) + n_out * (16 + 20) + 2 * nb * n_out * 5 + 2 * nb * 5
    else:
        cell += p * (derivative + nb * 20 + 2 * nb * 5)
    facet = nk * (28 + 16 + 32) + 2 * (2 * nk * nk * 5)
    bfacet = nk * (12 + 8 + 16) + 2 * nk * nk * 5
    flops = mf.nowned * cell + mf.fcells.shape[0] * facet + mf.bcells.shape[0] * bfacet
    flops = solver.comm.allreduce(flops, op=MPI.SUM) / solver.num_dofs
    return flops, matfree_data_bytes(solver) + 72


# ## Byte model

def matfree_data_bytes(solver: Solver):
    """Bytes per DOF of the matrix-free kernels' per-cell and per-facet data: the inverse
    Jacobian, 1/|det J|, the material index (and the dofmap, unless the DG numbering is cell by
    cell, as DOLFINx makes it); per facet: cells, codes, normal, length, the two cells' impedances."""
    mf = solver.matfree
    cell_data = [mf.Jinv[:mf.nowned], mf.invdet[:mf.nowned], mf.mat[:mf.nowned]]
    if not mf.contiguous:
        cell_data.append(mf.dofs[:mf.nowned])
    data = sum(a.nbytes for a in cell_data + [mf.fcells, mf.fcodes, mf.normal, mf.length])
    data += 2 * 2 * 8 * mf.fcells.shape[0]  # Zd, Zs of both cells
    return solver.comm.allreduce(data, op=MPI.SUM) / solver.num_dofs


def bytes_per_dof_stage(solver: Solver):
    """(operator bytes, RK vector bytes) per DOF·stage, as documented above."""
    n = solver.num_dofs
    if solver.matfree is not None:
        operator = matfree_data_bytes(solver) + 16 + 32
    else:
        info = solver.A.getInfo(info=solver.A.InfoType.GLOBAL_SUM)
        nnz = info["nz_used"]
        bs = solver.A.getBlockSize()
        operator = (8 * nnz + 4 * nnz / bs ** 2 + 4 * (n / bs + solver.comm.size)) / n + 16
    if solver.scheme in LOW_STORAGE:  # per stage dQ = A dQ + dt k, x += B dQ: 3 + 3 vector accesses
        return operator, 48.0
    a, b, _ = TABLEAUX[solver.scheme]
    s = len(b)
    per_stage = []
    for row in a:
        terms = sum(1 for aij in row if aij)
        per_stage.append(24 if terms == 1 else 16 + ((terms + 2) * 8 if terms else 0))
    rk = sum(per_stage) / s + (s + 2) * 8 / s
    return operator, rk


def flops_per_dof_step(solver: Solver):
    """Flops per DOF·step of ``solver``'s scheme (the models above): ADER's step, or a stage
    times the stages; None when assembled."""
    if solver.scheme == "ader":
        return ader_model(solver)[0]
    stage = flops_per_dof_stage(solver)
    return None if stage is None else stage * solver.num_stages
