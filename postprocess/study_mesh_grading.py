"""Study: model no more than the scene needs (issue 7, study 3).

The regularised crack-intersection problem (``scenarios/intersection.py``) on meshes that
differ only in their size field: uniform (the crack size everywhere) against graded (fine at
the cracks, coarsening by the factor 1.5 per size to ``h_far``), at two crack sizes.  For
each: cells, DOFs, wall time of the run to 1 ms, and the error of two quantities of
interest against the finest run (graded, h = 2.25 cm at the cracks; the scenario's full size
is 3 cm):

* the intersection time (when the growing crack connects to the natural fracture);
* the f_p-weighted loaded length of the natural fracture at 1 ms;
* the natural fracture's open area at 1 ms, the integral of its opening max(delta, 0) [m^2].

Adaptive meshes (:mod:`hydrofrac.adapt`; ``intersection.description(adapt=h_fine)``) run the
same problem with the cracks at the fine size ``h_fine`` (one run with them at twice it, as
before stop 45), the bulk at ``h_fine`` only where the indicator flags (bulk jumps above
``wellbore.ADAPT_TOL`` of the peak load) and a far size of 1 m reached within 0.75 m
(``wellbore.ADAPT_GRADING``): the work is counted in DOF·steps summed over the meshes,
remeshing included in the wall time.  For each adaptive mesh and quantity the study gives the work a static graded mesh
needs for the same error, over the adaptive work; the 3 cm and 4.5 cm graded and adaptive
meshes also run with their sizes 3.3 % and 6.7 % apart (:data:`ENSEMBLE`), and the same
ratios are taken on the ensembles' means.

A third variant, lower p in the far field, is not supported (one p per mesh).

    mpirun -n 2 python -m hydrofrac.postprocess.study_mesh_grading [--out DIR]

Writes ``mesh_grading.csv`` and ``mesh_grading.png`` (each error against the work, static
and adaptive meshes) and ``mesh_grading_means.csv`` (the ensembles' means and their ratios,
:data:`ENSEMBLE`) into ``postprocess/results`` (``--out``).
"""
from __future__ import annotations

import time
from pathlib import Path

from mpi4py import MPI

from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import save_figure, scenario, study_parser, timed_run

CASES = [  # name, h_crack, h_far, adaptive h_fine (None: a static mesh)
    ("graded, h = 2.25 cm (reference)", 0.0225, 0.45, None),
    ("graded, h = 3 cm (full size)", 0.03, 0.5, None),
    ("graded, h = 4.5 cm", 0.045, 0.6, None),
    ("graded, h = 6 cm (--quick)", 0.06, 0.8, None),
    ("uniform, h = 6 cm", 0.06, 0.06, None),
    ("adaptive, h = 3 cm on the cracks and where flagged", 0.03, 1.0, 0.03),
    ("adaptive, h = 4.5 cm on the cracks and where flagged", 0.045, 1.0, 0.045),
    ("adaptive, h = 6 cm on the cracks and where flagged", 0.06, 1.0, 0.06),
    # cracks at twice the fine size, as before stop 45 (which also graded within 0.5 m; docs/benchmarks.md)
    ("adaptive, h = 3 cm where flagged, 6 cm cracks", 0.06, 1.0, 0.03),
]
T_END = 1.0e-3
#: the meshes run again with every size times these factors (h_crack, and h_fine of an adaptive
#: mesh; h_far kept): the intersection time's error moves by up to 2-3x between such
#: neighbours, so the equal-error ratios are also taken on the means of each ensemble (five
#: members since stop 44: with three, the ratio's scatter was as large as what it measured)
_SIZES = (28 / 30, 29 / 30, 31 / 30, 32 / 30)
ENSEMBLE = {"graded, h = 3 cm (full size)": _SIZES, "graded, h = 4.5 cm": _SIZES,
            "adaptive, h = 3 cm on the cracks and where flagged": _SIZES,
            "adaptive, h = 4.5 cm on the cracks and where flagged": _SIZES}


def adaptive_run(problem, t_end, monitor):
    """Step as :func:`timed_run` does, remeshing through the problem's adaptive driver; returns
    (wall [s], DOF·steps summed over the meshes, the last problem)."""
    comm = problem.comm
    driver = problem.growth
    comm.barrier()
    t0 = time.perf_counter()
    problem.solver.update_energy()
    work = 0
    while problem.solver.t < t_end * (1 - 1e-12):
        solver = problem.solver
        solver.step()
        solver.update_energy()
        solver.check_stability()
        problem.after_step()
        monitor(problem)
        work += solver.num_dofs
        new = driver(problem)
        if new is not None:
            monitor.remeshed(problem, new)
            problem = new
    comm.barrier()
    return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX), work, problem


def run_case(h_crack, h_far, h_fine=None):
    from hydrofrac import wellbore
    ix = scenario("intersection")
    comm = MPI.COMM_WORLD
    t0 = time.perf_counter()
    desc = ix.description(regularized=True, h_crack=h_crack, h_far=h_far, adapt=h_fine)
    problem = wellbore.setup(desc, comm)[0]
    setup = time.perf_counter() - t0
    mon = ix.IntersectionMonitor([c.tag for c in problem.network.cracks if c.kind == "natural"])
    extra = {}
    if h_fine is None:
        wall = timed_run(problem, T_END, mon)
        work = problem.solver.num_dofs * problem.solver.step_count
    else:
        wall, work, problem = adaptive_run(problem, T_END, mon)
        rep = problem.growth.report()
        extra = {"remeshes": rep["adaptive_remeshes"], "cells_min": rep["cells_min"], "cells_max": rep["cells_max"]}
    solver = problem.solver
    acc = mon.accuracy(problem)
    return {"cells": solver.num_cells, "dofs": solver.num_dofs, "steps": solver.step_count, "dt": solver.dt,
            "dof_steps": work, "setup_s": setup, "wall_s": wall, "intersection_time": acc["intersection_time"],
            "nf_loaded_length": acc["nf_loaded_length_final"], "nf_open_area": acc["nf_open_area_final"], **extra}


QOIS = ("intersection_time_error", "loaded_length_error", "open_area_error")


def equal_error_work(static, key, error):
    """The work [DOF·steps] a static graded mesh needs for ``|error|`` in ``key``: log |error|
    against log work, interpolated between the two static meshes that bracket it, or extrapolated
    on the slope of the two nearest (beyond the finest or the coarsest); nan if the static errors
    do not fall with the work (no slope) or the error is 0.  ``static``: rows of the graded
    meshes but the reference, any order."""
    import numpy as np
    pts = sorted((r["dof_steps"], abs(r[key])) for r in static if r[key] != 0)
    if len(pts) < 2 or error == 0:
        return float("nan")
    w, e = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    k = int(np.clip(np.searchsorted(-e, -np.log(abs(error))), 1, len(pts) - 1))  # e falls along w
    slope = (e[k] - e[k - 1]) / (w[k] - w[k - 1])
    if not slope < 0:
        return float("nan")
    return float(np.exp(w[k - 1] + (np.log(abs(error)) - e[k - 1]) / slope))


def work_ratios(rows):
    """For every adaptive row and quantity: the static graded mesh's work for the same error
    (:func:`equal_error_work` over the graded rows but the reference and the neighbours of an
    ensemble) and its ratio to the adaptive work (> 1: adaptive needs less)."""
    static = [r for r in rows[1:] if r["h_fine"] is None and r["h_far"] > r["h_crack"] and not r.get("group")]
    for r in rows:
        for key in QOIS:
            name = key.replace("_error", "")
            if r["h_fine"] is None:
                r[f"static_work_same_{name}"] = r[f"work_ratio_{name}"] = ""
                continue
            w = equal_error_work(static, key, r[key])
            r[f"static_work_same_{name}"] = w
            r[f"work_ratio_{name}"] = w / r["dof_steps"]


def ensemble_means(rows):
    """One row per ensemble (:data:`ENSEMBLE`: a mesh and its neighbours, ``group`` naming the
    mesh) and per mesh outside one: the mean work and the mean |error| of each quantity, with
    the equal-error ratios of the adaptive means against the static graded means
    (:func:`work_ratios` on them)."""
    import numpy as np
    out = [rows[0]]
    for r in rows[1:]:
        if r.get("group"):
            continue
        members = [r] + [m for m in rows if m.get("group") == r["case"]]
        mean = {k: r[k] for k in ("case", "h_crack", "h_far", "h_fine")}
        mean["case"] = f"mean of {len(members)}: {r['case']}" if len(members) > 1 else r["case"]
        mean["dof_steps"] = float(np.mean([m["dof_steps"] for m in members]))
        for key in QOIS:
            mean[key] = float(np.mean([abs(m[key]) for m in members]))
        out.append(mean)
    work_ratios(out)
    return out


def chart(rows, png):
    """The three errors (absolute, against the reference) against the work in DOF·steps: the
    static graded meshes, the adaptive ones (cracks at h_fine, and at 2 h_fine) and the uniform one."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4))
    def coarse_cracks(r):
        return r["h_crack"] > r["h_fine"] * (1 + 1e-9)
    groups = [("graded (static)", lambda r: r["h_fine"] is None and r["h_far"] > r["h_crack"], "o-"),
              ("adaptive", lambda r: r["h_fine"] is not None and not coarse_cracks(r), "s-"),
              ("adaptive, cracks at 2 h_fine", lambda r: r["h_fine"] is not None and coarse_cracks(r), "D"),
              ("uniform", lambda r: r["h_far"] == r["h_crack"], "^")]
    for ax, key, unit, scale, title in ((axes[0], "intersection_time_error", "µs", 1e6, "intersection time"),
                                        (axes[1], "loaded_length_error", "m", 1.0, "loaded length at 1 ms"),
                                        (axes[2], "open_area_error", "mm²", 1e6, "open area at 1 ms")):
        for label, pick, style in groups:
            rs = sorted([r for r in rows[1:] if pick(r) and not r.get("group")], key=lambda r: r["dof_steps"])
            if rs:
                line, = ax.plot([r["dof_steps"] for r in rs], [abs(r[key]) * scale for r in rs], style, label=label)
                nb = [r for r in rows[1:] if pick(r) and r.get("group")]
                if nb:
                    ax.plot([r["dof_steps"] for r in nb], [abs(r[key]) * scale for r in nb], style[0],
                            color=line.get_color(), alpha=0.4, markersize=4,
                            label=f"{label}, sizes ±3–7 %")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("work [DOF·steps]")
        ax.set_ylabel(f"|error| [{unit}]")
        ax.set_title(f"{title} against the 2.25 cm reference", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    rows = []
    runs = [(name, hc, hf, hfine, "") for name, hc, hf, hfine in CASES]
    runs += [(f"{name}, sizes x {f:.3f}", hc * f, hf, None if hfine is None else hfine * f, name)
             for name, hc, hf, hfine in CASES for f in ENSEMBLE.get(name, ())]
    for name, hc, hf, hfine, group in runs:
        r = {"case": name, "group": group, "h_crack": hc, "h_far": hf, "h_fine": hfine, **run_case(hc, hf, hfine)}
        rows.append(r)
        if comm.rank == 0:
            print(f"[study] {name}: {r['cells']} cells, {r['dofs']} DOFs, {r['steps']} steps, "
                  f"{r['dof_steps']:.3g} DOF*steps, wall {r['wall_s']:.1f} s, "
                  f"intersection {r['intersection_time'] * 1e6:.1f} µs, loaded length {r['nf_loaded_length']:.3f} m, "
                  f"open area {r['nf_open_area'] * 1e6:.3f} mm²",
                  flush=True)
    ref = rows[0]
    for r in rows:
        r["intersection_time_error"] = r["intersection_time"] - ref["intersection_time"]
        r["loaded_length_error"] = r["nf_loaded_length"] - ref["nf_loaded_length"]
        r["open_area_error"] = r["nf_open_area"] - ref["nf_open_area"]
        r["ranks"] = comm.size
    work_ratios(rows)
    means = ensemble_means(rows)
    if comm.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        write_csv(out / "mesh_grading.csv", rows)
        chart(rows, out / "mesh_grading.png")
        for r in rows:
            print(f"[study] {r['case']:48s} {r['dof_steps']:9.3g} DOF*steps  wall {r['wall_s']:7.1f} s  "
                  f"intersection error "
                  f"{r['intersection_time_error'] * 1e6:+6.1f} µs  loaded-length error {r['loaded_length_error']:+.3f} m  "
                  f"open-area error {r['open_area_error'] * 1e6:+.3f} mm²",
                  flush=True)
            if r["h_fine"] is not None:
                print("[study]   a static graded mesh with the same error needs "
                      + ", ".join(f"{r['work_ratio_' + k.replace('_error', '')]:.2f}x the work ({k.split('_error')[0]})"
                                  for k in QOIS), flush=True)
        write_csv(out / "mesh_grading_means.csv", means)
        for r in means[1:]:
            if r["h_fine"] is not None:
                print(f"[study] {r['case']}: on the means, a static graded mesh with the same error needs "
                      + ", ".join(f"{r['work_ratio_' + k.replace('_error', '')]:.2f}x the work ({k.split('_error')[0]})"
                                  for k in QOIS), flush=True)
    return rows


if __name__ == "__main__":
    main()
