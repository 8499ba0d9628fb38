"""Study: the regularised contact map against the exact one, in two set-ups.

(a) Two bars (the two_bars scenario's strip, p = 2, 40 cells) close at ±v0 across a small
initial gap that shuts in the middle of a time step, stay in contact for 2L/c_d and fly apart.
(b) A debonded crack in a strip held at the confinement p0 at its ends, whose faces carry a
fluid pressure p0 (1 + A sin 2 pi t / T): the normal traction across the crack oscillates across
zero net, and the crack opens and closes once per period.
(c) The re-fracture scenario's --quick network (pre-meshed paths) from the start of the
pressure removal to the return of the load: the network closes under the confinement.  For
the exact map (fig. 3) and the regularised one (fig. 4) at several maximum penetrations δ'₀,
and at three time steps (the CFL step, 1/2 and 1/4 of it), with the opening clip disabled
(``ContactParams(clip=False)``: the dynamics alone) and, separately, enabled (its activations):

* chatter: contact-mode flips (η crossing 1/2) per Gauss point and millisecond;
* smoothness: the total variation of the mean normal traction history, relative to that of
  the exact answer (a plateau −Z_d v0 switched on and off: 2 Z_d v0), and its largest
  overshoot beyond −Z_d v0;
* convergence in dt: the L1 difference of the traction history from the next finer dt,
  and its rate;
* the energy balance error and the rebound-velocity error;
* the high-frequency energy radiated from the crack (:func:`hf_energy`);
* the largest penetration relative to the permitted |δ'₀| δ̃.

    python -m hydrofrac.postprocess.study_contact_regularisation [--quick] [--out DIR]

Writes ``contact_regularisation.csv`` and ``.png`` in ``--out`` (default postprocess/results).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import ROCK
from hydrofrac.interface import ContactParams
from hydrofrac.postprocess.rundata import write_csv
from hydrofrac.postprocess.study_common import log_axes, save_figure, scenario, study_parser
from hydrofrac.solver import CFL_DEFAULT

V0, L, GAP_STEPS, T_END = 1.0, 1.0, 10.5, 0.85e-3


def closing_bars(regularized, delta0, dt_factor, clip, nx=40, degree=2, local_flow=True):
    """The two_bars scenario with a gap that closes after GAP_STEPS CFL steps (mid-step), at
    CFL x dt_factor."""
    tb = scenario("two_bars")
    contact = ContactParams(delta0=delta0, regularized=regularized, clip=clip, local_flow=local_flow,
                            closing_speed=2 * V0)
    return tb.setup(degree=degree, nx=nx, L=L, v0=V0, gap_steps=GAP_STEPS, contact=contact,
                    cfl=CFL_DEFAULT["rk4"] * dt_factor), tb


def measure(regularized, delta0, dt_factor, clip, local_flow=True):
    problem, tb = closing_bars(regularized, delta0, dt_factor, clip, local_flow=local_flow)
    solver, iface, comm = problem.solver, problem.interface, problem.comm
    rec = tb.Recorder(L, V0)
    solver.update_energy()
    flips = 0
    last = None
    while solver.t < T_END * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        problem.after_step()
        rec(problem)
        on = iface.last["eta"] > 0.5
        if last is not None:
            flips += int(np.count_nonzero(on != last))
        last = on
    flips = comm.allreduce(flips, op=MPI.SUM)
    points = comm.allreduce(iface.last["eta"].size, op=MPI.SUM)
    acc = rec.accuracy(problem)
    sn = np.asarray(rec.sn)
    exact = -ROCK.Zd * V0
    rep = iface.contact_report()
    permitted = abs(iface.contact.delta0) * comm.allreduce(float(iface.delta_scale.max()) if iface.facets.size
                                                           else 0.0, op=MPI.MAX)
    return {
        "setup": "closing gap", "map": "regularised" if regularized else "exact",
        "delta0": iface.contact.delta0, "resolved": delta0 is None, "local_flow": local_flow,
        "dt_factor": dt_factor,
        "dt": solver.dt, "clip": clip,
        "flips_per_point_per_ms": flips / points / (T_END * 1e3),
        "traction_tv_rel": float(np.abs(np.diff(np.r_[0.0, sn, 0.0])).sum() / (2 * abs(exact))),
        "overshoot_rel": float(max(0.0, (-sn).max() / abs(exact) - 1)),
        "balance_error_rel": solver.energy.as_dict()["balance_error_relative"],
        "velocity_rel_error": acc.get("velocity_rel_error", float("nan")),
        "penetration_rel": rep["max_penetration"] / permitted,
        "clip_activations": rep["clip_activations"],
        "_t": np.asarray(rec.t), "_sn": sn,
    }


P0, AMP, PERIOD, CYCLES = 2.425e6, 0.5, 100e-6, 3


def oscillating_crack(regularized, delta0, dt_factor, clip, nx=40, degree=2, L=0.1, local_flow=True):
    """Set-up (b): the problem and the fluid pressure p(t)."""
    import math as _m

    from hydrofrac.boundary import Absorbing, Symmetry
    from hydrofrac.interface import Crack, Interface, crack_facet_indices
    from hydrofrac.problem import Problem
    from hydrofrac.solver import Solver
    tb = scenario("two_bars")
    mesh, tags = tb.make_mesh(MPI.COMM_WORLD, L, nx, ends=True)
    sigma0 = -P0 * np.eye(2)
    cracks = [Crack(tb.CRACK, friction=0.0, damage=1.0)]
    solver = Solver(mesh, degree, ROCK, facet_tags=tags, sigma0=sigma0, cfl=CFL_DEFAULT["rk4"] * dt_factor,
                    bcs=[Symmetry(tb.SIDES), Absorbing(tb.ENDS, stress=sigma0)],
                    crack_facets=crack_facet_indices(mesh, tags, cracks))
    # (a band resolved in time: at the jump 2 A p0 / Z_d of the pressure's swing)
    iface = Interface(solver, tags, cracks, contact=ContactParams(delta0=delta0, regularized=regularized, clip=clip,
                                                                  local_flow=local_flow,
                                                                  closing_speed=2 * AMP * P0 / ROCK.Zd))

    def pressure(t):
        return P0 * (1 + AMP * _m.sin(2 * _m.pi * t / PERIOD))
    iface.set_separation_law(lambda t: (np.array([-pressure(t), 0.0]), None))
    return Problem(solver, iface), pressure


def measure_b(regularized, delta0, dt_factor, clip, local_flow=True):
    problem, pressure = oscillating_crack(regularized, delta0, dt_factor, clip, local_flow=local_flow)
    solver, iface, comm = problem.solver, problem.interface, problem.comm
    solver.update_energy()
    t, sn, flips, last = [], [], 0, None
    while solver.t < CYCLES * PERIOD * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        on = iface.last["eta"] > 0.5
        if last is not None:
            flips += int(np.count_nonzero(on != last))
        last = on
        n = comm.allreduce(iface.last["eta"].size, op=MPI.SUM)
        t.append(solver.t)
        sn.append(comm.allreduce(float(iface.last["s_star"][:, 0].sum()), op=MPI.SUM) / n)
    flips = comm.allreduce(flips, op=MPI.SUM)
    points = comm.allreduce(iface.last["eta"].size, op=MPI.SUM)
    rep = iface.contact_report()
    sn = np.asarray(sn)
    return {
        "setup": "oscillating crack", "map": "regularised" if regularized else "exact",
        "delta0": iface.contact.delta0, "resolved": delta0 is None, "local_flow": local_flow,
        "dt_factor": dt_factor, "dt": solver.dt, "clip": clip,
        "flips_per_point_per_ms": flips / points / (CYCLES * PERIOD * 1e3),
        # the smooth answer's variation: the traction follows min(-p0... ) once up and down per period
        "traction_tv_rel": float(np.abs(np.diff(sn)).sum() / (CYCLES * 2 * 2 * AMP * P0)),
        "overshoot_rel": float("nan"),
        "balance_error_rel": solver.energy.as_dict()["balance_error_relative"],
        "velocity_rel_error": float("nan"),
        "penetration_rel": rep["max_penetration"] / rep["permitted_penetration_max"],
        "clip_activations": rep["clip_activations"],
        "_t": np.asarray(t), "_sn": sn,
    }


def refracture_unloading(regularized, delta0, dt_factor, clip, local_flow=True):
    """Set-up (c): the re-fracture scenario's --quick network on its pre-meshed paths, from the
    start of the pressure removal to the return of the load (the unloading phase)."""
    from dataclasses import replace

    from hydrofrac import wellbore
    rf = scenario("refracture")
    desc = rf.description(quick=True, degree=1)
    contact = replace(desc.contact, delta0=delta0, regularized=regularized, clip=clip, local_flow=local_flow)
    desc = replace(desc, contact=contact, cfl=CFL_DEFAULT["rk4"] * dt_factor)
    pressure, t_off, t_on, _ = rf.geometry(True)[3]
    return wellbore.setup(desc)[0], pressure.times[2], t_on


def measure_c(regularized, delta0, dt_factor, clip, local_flow=True):
    problem, t_start, t_on = refracture_unloading(regularized, delta0, dt_factor, clip, local_flow=local_flow)
    solver, iface, comm = problem.solver, problem.interface, problem.comm
    solver.update_energy()
    t, sn, flips, last, e0 = [], [], 0, None, None
    w = iface.weights.reshape(-1)
    wtot = comm.allreduce(float(w.sum()), op=MPI.SUM)
    while solver.t < t_on * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        problem.after_step()
        if solver.t < t_start:
            continue
        if e0 is None:
            e0 = solver.energy.balance_error
        on = iface.last["eta"] > 0.5
        if last is not None:
            flips += int(np.count_nonzero(on != last))
        last = on
        t.append(solver.t)
        sn.append(comm.allreduce(float(iface.last["s_star"][:, 0] @ w), op=MPI.SUM) / wtot)
    flips = comm.allreduce(flips, op=MPI.SUM)
    points = comm.allreduce(iface.last["eta"].size, op=MPI.SUM)
    rep = iface.contact_report()
    sn = np.asarray(sn)
    scale = solver.energy.initial + solver.energy.work_in
    return {
        "setup": "refracture unloading", "map": "regularised" if regularized else "exact",
        "delta0": iface.contact.delta0, "resolved": delta0 is None, "local_flow": local_flow,
        "dt_factor": dt_factor, "dt": solver.dt, "clip": clip,
        "flips_per_point_per_ms": flips / points / ((t_on - t_start) * 1e3),
        # relative to the smooth answer's: the mean traction falls once from its loaded value
        "traction_tv_rel": float(np.abs(np.diff(sn)).sum() / max(abs(sn[0] - sn[-1]), 1e-300)),
        "overshoot_rel": float("nan"),
        "balance_error_rel": float((solver.energy.balance_error - e0) / scale),
        "velocity_rel_error": float("nan"),
        "penetration_rel": rep["max_penetration"] / rep["permitted_penetration_max"],
        "clip_activations": rep["clip_activations"],
        "_t": np.asarray(t), "_sn": sn,
    }


def hf_energy(t, sn, dt_cfl, Z=ROCK.Zd):
    """High-frequency energy radiated from the crack [J/m^2 of crack]: a traction history s(t)
    on the faces radiates s^2 / Z per unit area and time into each side; its part above the
    frequency 1 / (10 dt_cfl) (signals of fewer than 10 CFL steps per period, which no
    resolved physics of these set-ups carries) is the spurious high-frequency radiation."""
    if len(sn) < 4:
        return float("nan")
    dt = t[1] - t[0]
    s = np.asarray(sn) - np.mean(sn)
    S = np.fft.rfft(s)
    f = np.fft.rfftfreq(s.size, dt)
    S[f < 1.0 / (10 * dt_cfl)] = 0.0
    hf = np.fft.irfft(S, n=s.size)
    return float(2 * np.sum(hf ** 2) * dt / Z)


def convergence(rows):
    """L1 difference of each run's traction history from the next finer dt's, and its rate."""
    def same(q, r):  # the same model at another dt (a resolved band is "the same" choice)
        band = (q.get("resolved") and r.get("resolved")) or (not q.get("resolved") and not r.get("resolved")
                                                              and q["delta0"] == r["delta0"])
        return (q["setup"] == r["setup"] and q["map"] == r["map"] and band and q["clip"] == r["clip"]
                and q["local_flow"] == r["local_flow"])

    for r in rows:
        finer = [q for q in rows if same(q, r) and math.isclose(q["dt_factor"], r["dt_factor"] / 2)]
        r["l1_to_finer"] = float("nan")
        if finer:
            q = finer[0]
            diff = np.abs(np.interp(r["_t"], q["_t"], q["_sn"]) - r["_sn"])
            r["l1_to_finer"] = float(np.sum(diff) * r["dt"] / (abs(np.mean(r["_sn"])) * r["_t"][-1]))
    for r in rows:
        finer = [q for q in rows if same(q, r) and math.isclose(q["dt_factor"], r["dt_factor"] / 2)]
        r["rate"] = (math.log2(r["l1_to_finer"] / finer[0]["l1_to_finer"])
                     if finer and finer[0]["l1_to_finer"] > 0 and np.isfinite(finer[0]["l1_to_finer"])
                     else float("nan"))


def chart(rows, png):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    setups = sorted({r["setup"] for r in rows})
    fig, axes = plt.subplots(len(setups), 3, figsize=(15, 4.2 * len(setups)), squeeze=False)
    for row_axes, setup in zip(axes, setups):
        free = [r for r in rows if not r["clip"] and r["setup"] == setup]
        for f, marker in zip(sorted({r["dt_factor"] for r in free}, reverse=True), "osd"):
            at = [r for r in free if r["dt_factor"] == f]
            reg = sorted([r for r in at if r["map"] == "regularised" and r["local_flow"] and not r["resolved"]],
                         key=lambda r: -r["delta0"])
            ex = [r for r in at if r["map"] == "exact"]
            plain = [r for r in at if r["map"] == "regularised" and not r["local_flow"]]
            res = [r for r in at if r["resolved"]]
            d0 = [abs(r["delta0"]) for r in reg]
            for ax, key in zip(row_axes, ("traction_tv_rel", "flips_per_point_per_ms", "penetration_rel")):
                ax.plot(d0, [r[key] for r in reg], marker + "-", label=f"regularised, exact closing flow, dt x {f:g}")
                colour = ax.lines[-1].get_color()
                if ex:
                    ax.axhline(ex[0][key], ls="--", lw=1, color=colour, label=f"exact map, dt x {f:g}")
                for rows_, m_, what in ((plain, "x", "plain RK sum"), (res, "*", "resolved in time")):
                    if rows_:
                        ax.plot([abs(r["delta0"]) for r in rows_], [r[key] for r in rows_], m_, ms=9, color=colour,
                                label=f"regularised, {what}, dt x {f:g}")
        for ax, title in zip(row_axes, ("traction total variation / smooth answer's", "mode flips per point per ms",
                                        "max penetration / permitted (clip off)")):
            ax.set_xscale("log")
            ax.set_xlabel("|δ'₀|")
            ax.set_title(f"{setup}: {title}", fontsize=10)
            log_axes(ax)
        row_axes[2].axhline(1.0, color="k", lw=1)
        row_axes[2].set_yscale("log")
    fig.suptitle("regularised contact map against the exact one")
    save_figure(fig, png)


def main(argv=None):
    args = study_parser(__doc__).parse_args(argv)
    deltas = (-0.01, -0.3) if args.quick else (-0.01, -0.03, -0.1, -0.3, -1.0)
    factors = (1.0, 0.5) if args.quick else (1.0, 0.5, 0.25)
    rows = []
    for f in factors:
        for m in (measure, measure_b, measure_c):
            rows.append(m(False, -0.01, f, clip=False))
            for clip in (False, True):
                # the default band through the plain Runge-Kutta sum (held by the clip) ...
                rows.append(m(True, -0.01, f, clip, local_flow=False))
                # ... and through the exact closing flow (the default), at every band
                for d0 in deltas:
                    rows.append(m(True, d0, f, clip))
                rows.append(m(True, None, f, clip))  # a band resolved in time (3 steps)
    cfl_dt = {}
    for r in rows:
        if r["dt_factor"] == 1.0:
            cfl_dt[r["setup"]] = r["dt"]
    for r in rows:
        r.setdefault("resolved", False)
        r["hf_energy"] = hf_energy(r["_t"], r["_sn"], cfl_dt[r["setup"]])
    convergence(rows)
    comm = MPI.COMM_WORLD
    if comm.rank == 0:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        table = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
        write_csv(out / "contact_regularisation.csv", table)
        chart(rows, out / "contact_regularisation.png")
        for r in table:
            print(f"[study] {r['setup']:17s} {r['map']:11s} d0 {r['delta0']:6.2f} dt x {r['dt_factor']:4.2f} "
                  f"clip {r['clip']!s:5s} TV {r['traction_tv_rel']:.4f} overshoot {r['overshoot_rel']:.4f} "
                  f"flips {r['flips_per_point_per_ms']:.2f} pen/permitted {r['penetration_rel']:.3g} "
                  f"clips {r['clip_activations']} "
                  f"L1 {r['l1_to_finer']:.3g} rate {r['rate']:.2f} vel err {r['velocity_rel_error']:.4f} "
                  f"balance {r['balance_error_rel']:.2e} HF {r['hf_energy']:.3g} J/m2"
                  f"{' (resolved)' if r['resolved'] else ''}{'' if r['local_flow'] else ' (plain RK)'}", flush=True)
    return rows


if __name__ == "__main__":
    main()
