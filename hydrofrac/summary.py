"""The closing summary of a run: what it computed, how fast, how accurately (``summary.json``)."""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Dict, Optional

import numpy as np

from . import compat, native


def build_summary(problem, name: str, wall: float, work: float, steps_run: int, remesh_info, accuracy: Dict,
                  outputs: Dict, unit_work, remeshes_timed: Optional[int] = None, compiling: float = 0.0) -> Dict:
    """The summary dictionary (collective: the time split and unit costs are reduced).
    ``remesh_info``: the run's remeshes; ``remeshes_timed``: those of this process (after a
    restart, the ones the timers saw; default all), the per-remesh times' divisor;
    ``unit_work``: this rank's (owned cell*stages, crack facet*stages) of the steps timed,
    counted step by step on the meshes the run went through; ``compiling``: this rank's seconds
    of the wall time spent compiling kernels at their first use (:func:`hydrofrac._jit.compile_seconds`),
    in the parts of the time split that first called them."""
    solver, comm = problem.solver, problem.comm
    summary = problem.summary()
    summary.update({
        "scenario": name,
        "wall_time_s": wall,
        "setup_time_s": solver.timers.t.get("setup", 0.0),
        # (a first run after an edit of hydrofrac/ or on a fresh machine; later runs load the kernels)
        "compiling_in_wall_s": comm.allreduce(float(compiling), op=compat.MPI.MAX),
        "dof_stages_per_s": work / wall if wall > 0 else float("nan"),
        "dof_stages_per_s_per_rank": work / wall / comm.size if wall > 0 else float("nan"),
        "energy": solver.energy.as_dict(),
        "time_split_s": {k: comm.allreduce(v, op=compat.MPI.MAX) for k, v in solver.timers.t.items()},
        "output": outputs,
    })
    summary["cost_us"] = unit_costs(solver, *unit_work)
    mf = getattr(solver, "matfree", None)
    summary["kernels"] = ("assembled operator (PETSc)" if mf is None else
                          native.describe() if mf.kernels == "c" else "numba")
    if remesh_info is not None:
        t_rm = solver.timers.t.get("remesh", 0.0)
        timed = int(remesh_info if remeshes_timed is None else remeshes_timed)
        n = max(timed, 1)
        # where a remesh's time goes (the largest rank's part; hydrofrac.adapt.carry_over), the
        # rest being the interface, the network, the hydraulics and the growth record
        mine = getattr(solver, "remesh_split_s", {})
        split = {k: comm.allreduce(mine.get(k, 0.0), op=compat.MPI.MAX) / n for k in REMESH_PARTS}
        split["rest"] = max(t_rm / n - sum(split.values()), 0.0)
        stepping = wall - t_rm
        crit = summary["time_split_s"].get("growth criterion", 0.0)
        summary["remeshing"] = {"remeshes": remesh_info, "remeshes_timed": timed,
                                "wall_s": t_rm, "share": t_rm / wall if wall > 0 else 0.0,
                                "per_remesh_s": t_rm / n, "solver_setup_per_remesh_s": split["solver set-up"],
                                "split_per_remesh_s": split,
                                # the growth criterion against the steps' cost (the wall time less remeshing)
                                "criterion_share_of_steps": crit / stepping if stepping > 0 else 0.0}
    if accuracy:
        summary["accuracy"] = accuracy
    return summary


#: the parts of a remesh's time in the summary, each the largest rank's: the new mesh's arrays
#: (Gmsh on rank 0 while the other ranks wait, a patch's exchanges), the DOLFINx mesh made from
#: them, the new solver's set-up and the transfer of fields and interface state
REMESH_PARTS = ("meshing", "distribution", "solver set-up", "transfer")


def write_summary(summary: Dict, out: Path, comm):
    if comm.rank == 0:
        with open(Path(out) / "summary.json", "w") as f:
            json.dump(summary, f, indent=2, default=float)
        print_summary(summary)


def unit_counts(solver):
    """This rank's (owned cells, crack facets) on the solver's mesh: the units of the bulk
    operator's and the interface kernel's work."""
    facets = sum(e.facets.size for e in solver.extensions if hasattr(e, "facets"))
    return compat.num_cells_local(solver.mesh), facets


def unit_costs(solver, cell_stages: float, facet_stages: float) -> Dict[str, float]:
    """Wall time per unit of work, summed over ranks [µs]: the bulk operator per
    cell*stage and the interface kernel per crack facet*stage (docs/benchmarks.md), the work
    being this rank's ``cell_stages`` and ``facet_stages``, counted step by step on the
    meshes the run went through."""
    t = solver.timers.t
    loc = np.array([t.get("bulk operator", 0.0), cell_stages, t.get("interface kernel", 0.0), facet_stages],
                   dtype=float)
    tot = np.zeros(4)
    solver.comm.Allreduce(loc, tot, op=compat.MPI.SUM)
    out = {"bulk_per_cell_stage": 1e6 * tot[0] / max(tot[1], 1)}
    if tot[3] > 0:
        out["interface_per_facet_stage"] = 1e6 * tot[2] / tot[3]
        out["crack_facets"] = int(solver.comm.allreduce(unit_counts(solver)[1], op=compat.MPI.SUM))
    return out


def print_summary(s: Dict, file=sys.stdout):
    e = s["energy"]
    lines = [
        f"[hydrofrac] ---- summary: {s['scenario']} ----",
        f"  mesh        {s['cells']} cells, {s['dofs']} DOFs, p = {s['degree']}, {s['ranks']} rank(s)",
        f"  time        {s['steps']} steps of dt = {s['dt']:.4g} s ({s['scheme']}, CFL {s['cfl']:.3g}) "
        f"to t = {s['simulated_time']:.6g} s",
        f"  speed       wall {s['wall_time_s']:.2f} s (+ setup {s['setup_time_s']:.2f} s), "
        f"{s['dof_stages_per_s']:.3g} DOF*stages/s ({s['dof_stages_per_s_per_rank']:.3g} per rank)"
        + (f"; {s['compiling_in_wall_s']:.2f} s of the wall time compiled kernels at their first use "
           f"(a second run loads them)" if s.get("compiling_in_wall_s", 0.0) >= 0.01 else ""),
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
        if "kernels" in s:
            line += f"; kernels: {s['kernels']}"
        lines.append(line)
    if "contact" in s:
        c = s["contact"]
        lines.append(f"  contact     max penetration {c['max_penetration']:.3g} m "
                     f"(permitted {c['permitted_penetration_max']:.3g} m), opening clip acted "
                     f"{c['clip_activations']} times (deepest {c['clip_depth_max']:.3g}x the permitted penetration)")
        if c.get("band_steps_met") is not None:
            lines.append(f"  contact     delta'_0 = {c['delta0']:.3g}{' (resolved in time)' if c['resolved'] else ''}: "
                         f"the band spans {c['band_steps_met']:.3g} steps at the fastest closing met "
                         f"({c['closing_speed_met']:.3g} m/s)")
    if "remeshing" in s:
        r = s["remeshing"]
        parts = ", ".join(f"{k} {v:.3f}" for k, v in r.get("split_per_remesh_s", {}).items())
        lines.append(f"  remeshing   {r['remeshes']} remeshes, {r['wall_s']:.2f} s "
                     f"({100 * r['share']:.0f}% of the wall time), {r.get('per_remesh_s', 0.0):.3f} s each "
                     f"({parts} s); the growth criterion "
                     f"{100 * r.get('criterion_share_of_steps', 0.0):.1f}% of the steps' cost")
    for k, v in s.get("accuracy", {}).items():
        lines.append(f"  accuracy    {k} = {v:.4g}" if isinstance(v, float) else f"  accuracy    {k} = {v}")
    lines.append(f"  output      {s['output']['paraview']} (ParaView), {s['output']['history']}")
    print("\n".join(lines), file=file, flush=True)
