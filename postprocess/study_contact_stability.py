"""Study: stability where penalty contact struggles (issue 7, study 2).

Two rock bars close at ±1 m/s on a debonded interface (verification case 9), at a
small size (p = 2, 20 cells along 2 m; the contact behaviour is local, so the size does
not matter).  Three contact treatments on the same mesh:

* **penalty** (baseline): normal traction -kappa <-delta>, kappa scanned over decades;
* **this method**: Riemann contact with the regularised eta, delta'_0 scanned;
* **unregularised eta** (exact map of model.md §4), at the bulk CFL step.

A second experiment starts the bars 1 µm apart, so that the interface *closes* during a
step: the largest penetration against the time step, for the exact and the regularised
eta.  The exact map lets the faces overshoot by up to the closing speed times the step
(it only switches to contact once delta <= 0 has happened); the regularised map caps the
penetration at |delta'_0| delta~ whatever the step.

For each case the largest stable time step is found by halving from the bulk CFL step.
A step counts as stable when 100 µs of contact run without NaN or energy growth
(``Solver.check_stability``) *and* the bars stay in contact: the mean traction over the
last 3/4 of the window is at least half the exact -Z_d v0 (a stiff penalty spring at
too large a step can also throw the bars apart without any energy growth).  The largest penetration and the contact traction history of the largest stable
run are recorded.  Writes ``contact_stability.csv`` and ``contact_stability.png``
(time step and penetration against kappa and against delta'_0; the traction history)
into ``postprocess/results`` (``--out``).

    python -m hydrofrac.postprocess.study_contact_stability [--quick] [--out DIR]

Expected (and measured, see docs/benchmarks.md): the penalty's stable step falls like
Z~/kappa once kappa exceeds ~Z~/dt_CFL while its penetration falls like p/kappa; the
Riemann contact keeps the bulk CFL step for every delta'_0, with penetration
|delta'_0| delta~.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.boundary import Symmetry
from hydrofrac.interface import ContactParams, Crack, Interface, crack_facet_indices
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import log_axes, save_figure, scenario, study_parser
from hydrofrac.solver import BlowUpError, Solver

CRACK, SIDES = scenario("two_bars").CRACK, scenario("two_bars").SIDES
L, V0 = 1.0, 1.0
T_WINDOW = 100e-6
KAPPAS = (1e11, 1e12, 1e13, 1e14, 1e15)
DELTA0S = (-1e-1, -1e-2, -1e-3, -1e-4)


def bars(comm, nx):
    """The two-bar strip of ``scenarios/two_bars.py`` (crack at x = 0, symmetry sides)."""
    return scenario("two_bars").make_mesh(comm, L, nx)


def run_case(mesh, tags, contact: ContactParams, dt_factor: float, degree=2, t_window=T_WINDOW, gap=0.0):
    """Run the impact for ``t_window`` (the bars start ``gap`` apart); returns (stable, dt,
    penetration, times, mean traction)."""
    cracks = [Crack(CRACK, friction=0.0, damage=1.0, opening=gap)]
    facets = crack_facet_indices(mesh, tags, cracks)
    probe = Solver(mesh, degree, ROCK, facet_tags=tags, bcs=[Symmetry(SIDES)], crack_facets=facets)
    solver = Solver(mesh, degree, ROCK, facet_tags=tags, bcs=[Symmetry(SIDES)], crack_facets=facets,
                    dt=probe.dt * dt_factor)
    solver.set_initial_state(lambda x: np.vstack([np.where(x[0] < 0, V0, -V0)] + [0 * x[0]] * 4), by_cell=True)
    iface = Interface(solver, tags, cracks, contact=contact)
    solver.attach(iface)
    comm = solver.comm
    n = comm.allreduce(iface.facets.size * iface.nq, op=MPI.SUM)
    ts, sn = [], []
    solver.update_energy()
    try:
        while solver.t < t_window * (1 - 1e-9):
            solver.step()
            solver.update_energy()
            solver.check_stability()
            ts.append(solver.t)
            sn.append(comm.allreduce(float(iface.last["s_star"][:, 0].sum()), op=MPI.SUM) / n)
        stable = True
    except BlowUpError:
        stable = False
    sn = np.array(sn)
    if stable and sn.size:
        plateau = sn[len(sn) // 4:].mean()
        stable = plateau / (-ROCK.Zd * V0) > 0.5
    return stable, solver.dt, iface.max_penetration(), np.array(ts), sn


def largest_stable(mesh, tags, contact, max_halvings=12):
    """Halve the step from the bulk CFL step until the run is stable."""
    for k in range(max_halvings + 1):
        stable, dt, pen, ts, sn = run_case(mesh, tags, contact, 0.5 ** k)
        if stable:
            return dict(stable_dt=dt, halvings=k, penetration=pen, t=ts, sn=sn)
    return dict(stable_dt=np.nan, halvings=max_halvings + 1, penetration=np.nan, t=ts, sn=sn)


def chatter(sn):
    """Total variation of the mean contact traction over the last 3/4 of the window,
    relative to the exact contact stress Z_d v0."""
    s = sn[len(sn) // 4:]
    return float(np.abs(np.diff(s)).sum() / (ROCK.Zd * V0)) if s.size > 1 else float("nan")


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    comm = MPI.COMM_WORLD
    mesh, tags = bars(comm, 20)
    kappas = KAPPAS[1::2] if args.quick else KAPPAS
    deltas = DELTA0S[::3] if args.quick else DELTA0S
    rows, series = [], {}
    dt_cfl = run_case(mesh, tags, ContactParams(), 1.0, t_window=0.0)[1]
    cases = ([("penalty", kappa, ContactParams(penalty=kappa), f"penalty kappa={kappa:.0e}") for kappa in kappas]
             + [("riemann", d0, ContactParams(delta0=d0), f"regularised eta, delta0'={d0:g}") for d0 in deltas]
             + [("exact_eta", 0.0, ContactParams(regularized=False), "unregularised eta")])
    for method, parameter, contact, label in cases:
        r = largest_stable(mesh, tags, contact)
        rows.append({"method": method, "parameter": parameter,
                     **{k: r[k] for k in ("stable_dt", "halvings", "penetration")}, "chatter": chatter(r["sn"])})
        series[label] = (r["t"], r["sn"])
    for name, contact in (("closure_exact_eta", ContactParams(regularized=False)),
                          ("closure_regularised", ContactParams())):
        for k in (0, 2, 4):
            stable, dt, pen, _, sn = run_case(mesh, tags, contact, 0.5 ** k, gap=1e-6)
            rows.append({"method": name, "parameter": 0.5 ** k, "stable_dt": dt if stable else np.nan,
                         "halvings": k, "penetration": pen, "chatter": chatter(sn)})
    if comm.rank != 0:
        return rows
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "contact_stability.csv", rows)
    for row in rows:
        print(f"[study] {row['method']:19s} {row['parameter']:9.3g}: largest stable dt {row['stable_dt']:.3g} s "
              f"({row['stable_dt'] / dt_cfl:.3g} x the bulk CFL step), penetration {row['penetration']:.3g} m, "
              f"traction chatter {row['chatter']:.3g}", flush=True)
    plot(rows, series, dt_cfl, out / "contact_stability.png")
    print(f"[study] wrote {out}/contact_stability.csv and contact_stability.png", flush=True)
    return rows


def plot(rows, series, dt_cfl, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 4, figsize=(17, 3.8), dpi=80)
    pen = [r for r in rows if r["method"] == "penalty"]
    rie = [r for r in rows if r["method"] == "riemann"]
    delta_t = ROCK.Zd  # for the second x axis label only
    ax = axes[0]
    ax.loglog([r["parameter"] for r in pen], [r["stable_dt"] / dt_cfl for r in pen], "o-", label="stable dt / dt_CFL")
    ax.loglog([r["parameter"] for r in pen], [r["penetration"] for r in pen], "s--", label="penetration [m]")
    ax.set_xlabel("penalty stiffness kappa [Pa/m]")
    ax.set_title("penalty contact", fontsize=10)
    ax = axes[1]
    x = [abs(r["parameter"]) for r in rie]
    ax.loglog(x, [r["stable_dt"] / dt_cfl for r in rie], "o-", label="stable dt / dt_CFL")
    ax.loglog(x, [r["penetration"] for r in rie], "s--", label="penetration [m]")
    ax.invert_xaxis()
    ax.set_xlabel("|delta'_0| (maximum penetration / delta~)")
    ax.set_title("Riemann contact, regularised eta", fontsize=10)
    ax = axes[2]
    for name, (t, sn) in series.items():
        if name.startswith("penalty") and name != f"penalty kappa={pen[-1]['parameter']:.0e}":
            continue
        if name.startswith("regularised") and not name.endswith(f"{rie[0]['parameter']:g}"):
            continue
        ax.plot(np.asarray(t) * 1e6, np.asarray(sn) / 1e6, label=name, lw=1)
    ax.axhline(-delta_t * V0 / 1e6, color="k", ls=":", lw=0.8, label="exact -Z_d v0")
    ax.set_xlabel("t [µs]")
    ax.set_ylabel("mean contact traction [MPa]")
    ax.set_title("traction history (largest stable step)", fontsize=10)
    ax.legend(fontsize=7)
    ax = axes[3]
    for method, label in (("closure_exact_eta", "unregularised eta"), ("closure_regularised", "regularised eta")):
        rs = [r for r in rows if r["method"] == method]
        ax.loglog([r["parameter"] for r in rs], [max(r["penetration"], 1e-12) for r in rs], "o-", label=label)
    ax.set_xlabel("time step / dt_CFL")
    ax.set_ylabel("largest penetration [m]")
    ax.set_title("closing a 1 µm gap at 2 m/s", fontsize=10)
    log_axes(axes[0], axes[1], axes[3])
    save_figure(fig, png)


if __name__ == "__main__":
    main()
