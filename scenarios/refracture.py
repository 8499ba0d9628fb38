# # Re-fracturing: load on, off, on (paper §3.2, figs. 10-12)
#
# Four perforations leave a wellbore in confined rock (no natural fracture).
# The fluid pressure p_h is applied (2.425 → 19.4 MPa in 1 µs), held, removed
# completely (p_h = 0 by 5 ms) and re-applied from 8 ms.  The cracks grow while
# loaded; after the removal the confinement closes
# them: the regularised contact fraction η takes them smoothly from separation
# to contact (the opening never goes below the permitted penetration).  When the
# load comes back, the pressure factor f_p re-applies it from the perforations
# outward, because a crack vertex uses the aperture of *all* loaded facets that
# meet there (model.md §5).
#
# The fluid is finite (docs/model.md, "A finite fluid volume"): a pump puts in `--pump-rate`
# Q = 1.5 m²/s (per m of thickness) while the load is on, the fluid flows back out with the
# removal, and the load ends at the fluid's front.  The cracks therefore grow only as far as
# the fluid drives them, close once it has flowed back, and the returning fluid re-loads them
# from the perforations outward.  `--pump-rate inf` is the paper's unlimited supply: then the
# cracks reach the outer boundary while the load is held and stay open in the off period
# (docs/studies/scenarios.md).
#
# The cracks grow freely from the perforation tips with Gmsh remeshing (the intersection
# scenario's driver and criterion: `hydrofrac.wellbore.growth_driver`); microcracks nucleate
# where the bulk reaches the strength (4 per run).  `--premeshed` grows the cracks along radial
# potential paths (bonded interfaces, D = 0) of 2.5 m (`--quick` 0.4 m) instead.
#
#     mpirun -n 2 python scenarios/refracture.py [--quick] [--premeshed] [--out DIR]
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from mpi4py import MPI

from hydrofrac import CONFINEMENT, cli, wellbore
from hydrofrac.boundary import PiecewiseLinear
from hydrofrac.hydraulics import network_distance
from hydrofrac.interface import DamageParams
from hydrofrac.meshes.fractures import Domain, Perforation
from hydrofrac.run import Monitor, RunOptions
from hydrofrac.run import run as run_problem

P_PEAK = 19.4e6
# microcracks per run, (full size, --quick)
NUCLEATION_CAP = (4, 4)
# the pump rate [m²/s per m of thickness] while the load is on (docs/studies/scenarios.md)
PUMP_RATE = 1.5
ANGLES = (0.0, 90.0, 180.0, 270.0)


# ## Load history (fig. 10)
# On at 1 µs, held to `t_hold`, removed linearly by `t_off`, off until `t_on`,
# re-applied in 10 µs and held to `t_end`.  Paper: 4, 5, 8 and 10 ms.
def load_history(t_hold=4e-3, t_off=5e-3, t_on=8e-3, t_end=10e-3, p0=CONFINEMENT, peak=P_PEAK):
    t = [0.0, 1e-6, t_hold, t_off, t_on, t_on + 1e-5, t_end]
    return PiecewiseLinear(t, [p0, peak, peak, 0.0, 0.0, peak, peak]), t_off, t_on, t_end


# ## The fluid (docs/model.md, "A finite fluid volume")
# With a pump rate Q [m²/s per m of thickness] the fluid in the network is V(t): pumped in at Q
# while the load is on, flowing back out with the removal (V = 0 when p_h = 0) and pumped in
# again from the re-loading.  The load ends at the fluid's front, so the cracks grow only as far
# as the fluid drives them, and the returning load spreads from the perforations outward at the
# rate the fluid fills the open network.  Without it (`--pump-rate inf`) the supply is unlimited.
def fluid_volume(pressure, rate):
    """V(t) of a pump at ``rate`` [m²/s] on the on/off/on ``pressure`` history, or None for inf."""
    if math.isinf(rate):
        return None
    t = list(pressure.times)  # 0, ramp, hold end, removed, re-load, its ramp, end
    pumped = rate * (t[2] - t[0])
    return PiecewiseLinear([t[0], t[2], t[3], t[4], t[6]], [0.0, pumped, 0.0, 0.0, rate * (t[6] - t[4])])


def geometry(quick=False, h_crack=None, h_far=None):
    """Domain, perforations, potential-path lengths and load history (``--quick``: smaller);
    ``h_crack``, ``h_far`` [m]: the mesh sizes at the cracks and far from them (default 0.04 and
    0.8, ``--quick`` 0.05 and 0.5; the growth's Δa and r are in facet sizes, so they scale too)."""
    if quick:
        # small cracks close quickly: a 2 ms version of the history
        dom = Domain(half_width=1.2, half_height=1.2, wellbore_radius=0.1, h_crack=h_crack or 0.05,
                     h_far=h_far or 0.5, grading=0.8)
        perfs = [Perforation(a, 0.15, width=1e-4) for a in ANGLES]
        return dom, perfs, [0.4] * 4, load_history(0.3e-3, 0.4e-3, 1.5e-3, 1.8e-3)
    dom = Domain(half_width=4.0, half_height=4.0, wellbore_radius=0.1, h_crack=h_crack or 0.04, h_far=h_far or 0.8,
                 grading=1.5)
    perfs = [Perforation(a, 0.3, width=1e-4) for a in ANGLES]
    return dom, perfs, [2.5] * 4, load_history()


def description(quick=False, degree=2, tau=30e-6, growth=None, connected=False,
                pump_rate=PUMP_RATE, adapt=None, adapt_tol=wellbore.ADAPT_TOL, h_crack=None,
                h_far=None, scheme="rk4", cfl=None) -> wellbore.Wellbore:
    """The problem as data: free growth (``growth``) or the pre-meshed paths, and the fluid of a
    pump at ``pump_rate`` [m²/s] (inf: an unlimited supply); ``adapt`` [m]: adaptive meshes with
    that fine size (:func:`hydrofrac.wellbore.adaptive`); ``h_crack``, ``h_far``: see
    :func:`geometry`; ``scheme``, ``cfl``: the time scheme and its CFL constant (None: the
    scheme's documented one)."""
    dom, perfs, lengths, (pressure, _, _, _) = geometry(quick, h_crack, h_far)
    paths = wellbore.radial_paths(dom, perfs, lengths)
    desc = wellbore.Wellbore(dom, perfs, pressure, paths=() if growth else paths, regularized=True, degree=degree,
                             damage=DamageParams(tau=tau), growth=growth, connected=connected,
                             volume=fluid_volume(pressure, pump_rate), scheme=scheme, cfl=cfl)
    return desc if adapt is None else wellbore.adaptive(desc, adapt, adapt_tol, h_crack=h_crack, h_far=h_far)


def setup(comm=MPI.COMM_WORLD, record=None, **params):
    """The built problem (``problem.growth`` is its growth driver, if it grows freely)."""
    return wellbore.setup(description(**params), comm, record=record)[0]


# ## What we watch
# * after the removal: the fraction of the network in separation, the smallest
#   opening (never below δ'₀ δ̃) and the total energy (no growth);
# * after re-loading: when each network facet that had unloaded (f_p ≤ 0.5 when the
#   load returns) first reaches f_p > 0.5, and its distance along the network from
#   the perforations.
class RefractureMonitor(Monitor):
    checkpointed = ("t_reach", "still_loaded", "loaded_before_on", "energy_after_off", "sep_fraction")

    def __init__(self, t_off, t_on):
        self.t_off, self.t_on = t_off, t_on
        self.t_reach = None
        # facets with f_p > 0.5 at the last step before the load returns (never unloaded): a
        # closed facet holds little fluid, so the first step of the returning load may fill the
        # first facet beyond a perforation, which had unloaded
        self.loaded_before_on = None
        self.still_loaded = None  # that record, kept from the first step at or after t_on
        self.energy_after_off = []
        self.sep_fraction = []

    def remeshed(self, old, new):
        """Carry the per-facet record (re-load time, loaded when the load returned) to the new
        crack facets: from the old facet whose midpoint is nearest, if it lies within half a
        facet length (a facet of a new segment has no record)."""
        old_if, new_if, comm = old.interface, new.interface, new.comm
        mid = lambda f: 0.5 * (f.va + f.vb)  # noqa: E731
        none = np.zeros(old_if.facets.size, bool)
        masks = [m if m is not None else none for m in (self.still_loaded, self.loaded_before_on)]
        parts = comm.allgather((mid(old_if), self.t_reach, *masks))
        P = np.concatenate([p[0] for p in parts]).reshape(-1, 2)
        T = np.concatenate([p[1] for p in parts])
        K = [np.concatenate([p[k] for p in parts]).astype(bool) for k in (2, 3)]
        self.t_reach = np.full(new_if.facets.size, np.inf)
        kept = [np.zeros(new_if.facets.size, bool) for _ in K]
        if P.size and new_if.facets.size:
            from scipy.spatial import cKDTree
            dist, j = cKDTree(P).query(mid(new_if))
            near = dist <= 0.5 * new_if.length
            self.t_reach[near] = T[j[near]]
            for k, m in zip(kept, K):
                k[near] = m[j[near]]
        if self.still_loaded is not None:
            self.still_loaded = kept[0]
        if self.loaded_before_on is not None:
            self.loaded_before_on = kept[1]

    def __call__(self, problem):
        hyd, iface, comm, t = problem.hydraulics, problem.interface, problem.comm, problem.t
        if self.t_reach is None:
            self.t_reach = np.full(iface.facets.size, np.inf)
        net = hyd.network[:, None] * iface.weights
        # (one reduction a step) the network's separated, closed and whole length; closed: at or
        # past contact, delta <= 0 up to round-off (1e-9 delta~: a face that never opened has
        # delta = 0, and the last bits of a sum must not move it out of contact)
        sums = np.array([float((iface.separated() * net).sum()),
                         float(((iface.state[1] <= 1e-9 * iface.delta_scale[:, None]) * net).sum()),
                         float(net.sum())])
        comm.Allreduce(MPI.IN_PLACE, sums, op=MPI.SUM)  # (a buffer: no pickling, a step)
        sep, closed, tot = sums.tolist()
        self.sep_fraction.append((t, sep / max(tot, 1e-300), closed / max(tot, 1e-300)))
        if t >= self.t_off:
            self.energy_after_off.append((t, problem.solver.energy.balance_error))
            loaded = hyd.facet_fp() > 0.5
            if t < self.t_on:
                self.loaded_before_on = loaded
                return
            if self.still_loaded is None:
                self.still_loaded = (self.loaded_before_on if self.loaded_before_on is not None else loaded).copy()
            hit = loaded & ~np.isfinite(self.t_reach)
            self.t_reach[hit] = t

    def history(self, problem):
        t, f = self.sep_fraction[-1][:2] if self.sep_fraction else (0.0, 0.0)
        aperture_volume, wet_length, fluid = problem.hydraulics.fluid()
        return {"p_h": problem.hydraulics.params.pressure(problem.t), "separated_fraction": f,
                "network_length": problem.hydraulics.loaded_length()[1],
                # the loaded network's open volume, the fluid's length along it and V(t)
                "aperture_volume": aperture_volume, "wet_length": wet_length, "fluid_volume": fluid}

    def accuracy(self, problem):
        iface, hyd, comm, solver = problem.interface, problem.hydraulics, problem.comm, problem.solver
        # order of re-loading against the distance along the network (gathered on all ranks)
        still = self.still_loaded if self.still_loaded is not None else np.zeros(self.t_reach.size, bool)
        parts = comm.allgather((hyd.vertices, iface.length, hyd.network, hyd.source, self.t_reach, still,
                                iface.crack_tag))
        V = np.concatenate([p[0] for p in parts]).reshape(-1, 2)
        L = np.concatenate([p[1] for p in parts])
        A = np.concatenate([p[2] for p in parts]).astype(bool)
        S = np.concatenate([p[3] for p in parts]).astype(bool)
        T = np.concatenate([p[4] for p in parts])
        K = np.concatenate([p[5] for p in parts]).astype(bool)
        tag = np.concatenate([p[6] for p in parts])
        dist = network_distance(V, L, A, S)
        # the order counts the facets that were unloaded when the load returned: on the main
        # cracks (the arms grown from the perforations, the paper's claim), and on the whole
        # network (with the microcracks that joined it)
        sel = A & ~S & ~K & np.isfinite(T) & np.isfinite(dist)
        arms = sel & np.isin(tag, self.arm_tags(problem))
        from scipy.stats import spearmanr
        rho, rho_net = (float(spearmanr(dist[m], T[m]).correlation) if m.sum() > 2 else float("nan")
                        for m in (arms, sel))
        e = np.array(self.energy_after_off) if self.energy_after_off else np.zeros((0, 2))
        off = e[e[:, 0] < self.t_on]  # from the end of the removal to the re-loading
        sep = np.array(self.sep_fraction)
        before_on = sep[(sep[:, 0] >= self.t_off) & (sep[:, 0] < self.t_on)]
        floor = float(comm.allreduce(float((iface.contact.delta0 * iface.delta_scale).min())
                                     if iface.delta_scale.size else 0.0, op=MPI.MIN))
        return {
            "reload_order_spearman": rho, "reloaded_arm_facets": int(arms.sum()),
            "reload_order_spearman_network": rho_net,
            # the network connected to the perforations (a microcrack that never joined it has no load)
            "reloaded_facets": int(sel.sum()), "network_facets": int((A & ~S & np.isfinite(dist)).sum()),
            "unconnected_facets": int((A & ~S & ~np.isfinite(dist)).sum()),
            "loaded_when_reloading": int((A & ~S & K & np.isfinite(dist)).sum()),
            # energy may rise while the confinement closes the cracks (work relative to sigma0);
            # spurious growth shows as a growing balance error
            "balance_error_growth_while_off": float(off[-1, 1] - off[0, 1]) if len(off) > 1 else 0.0,
            # and from the re-loading to the end, for comparison (the budget's time-discretisation
            # error of the fast re-load, not a spurious growth)
            "balance_error_growth_after_reload": float(e[-1, 1] - off[-1, 1]) if len(off) and len(e) else 0.0,
            "energy_scale": float(solver.energy.initial + solver.energy.work_in),
            "separated_fraction_before_reload": float(before_on[-1, 1]) if len(before_on) else float("nan"),
            # closed: the faces at or past contact (delta <= 0, inside the contact band)
            "closed_fraction_before_reload": (float(before_on[-1, 2]) if len(before_on) and before_on.shape[1] > 2
                                              else float("nan")),
            "min_opening": -iface.max_penetration(), "opening_floor": floor,
            **self.microcracks(problem),
        }

    @staticmethod
    def arm_tags(problem):
        """Facet tags of the main cracks: the paths grown from the perforation tips (the first
        tips of the growth driver, no event's new tip), or every pre-meshed path."""
        drv = getattr(problem, "growth", None)
        if drv is None:
            return [c.tag for c in problem.network.cracks if c.kind == "path"] if problem.network is not None else []
        new = set()
        for e in drv.tree:
            child = e["child"]
            if e["event"] == "branch":
                new.update(child[1:])
            elif e["event"] == "nucleation":
                new.update(child)
            elif child is not None:
                new.add(child)
        return [drv.tags[i] for i in range(len(drv.tips)) if i not in new]

    def microcracks(self, problem):
        """The nucleated cracks at the end (figs. 12g-i): how many are closed (δ ≤ 0 on at least
        half their length: in contact), how many carry no hydraulic load, and how many of the
        closed ones are arrested (no extension since the load returned)."""
        drv = getattr(problem, "growth", None)
        if drv is None:
            return {}
        iface, hyd, comm = problem.interface, problem.hydraulics, problem.comm
        cracks = [c["child"] for c in drv.tree if c["event"] == "nucleation"]
        last = {}
        for t, i, _, _ in drv.events:
            last[i] = max(last.get(i, -np.inf), t)
        closed = unloaded = arrested = 0
        w = iface.weights
        for tips in cracks:
            on = np.isin(iface.crack_tag, [drv.tags[j] for j in tips])
            tot = comm.allreduce(np.array([w[on].sum(), (w[on] * (iface.state[1][on] <= 0)).sum(),
                                           (w[on] * hyd.fp_q[on]).sum()]), op=MPI.SUM)
            is_closed = tot[0] > 0 and tot[1] >= 0.5 * tot[0]
            closed += is_closed
            unloaded += tot[0] > 0 and tot[2] == 0
            arrested += is_closed and max(last.get(j, -np.inf) for j in tips) < self.t_on
        return {"microcracks": len(cracks), "microcracks_closed_at_end": int(closed),
                "microcracks_unloaded_at_end": int(unloaded), "microcracks_arrested_closed": int(arrested)}

    def report(self, acc):
        return (f"[refracture] separated fraction just before re-loading {acc['separated_fraction_before_reload']:.3f}; "
                f"re-loading order vs distance from the perforations: Spearman {acc['reload_order_spearman']:.3f} "
                f"over {acc['reloaded_arm_facets']} facets of the main cracks, "
                f"{acc['reload_order_spearman_network']:.3f} over the network's {acc['reloaded_facets']}")


def run(problem, options: RunOptions, t_off, t_on):
    """Run ``problem`` with the re-fracture monitor (``t_off``, ``t_on``: the end of the
    removal and the re-loading)."""
    return run_problem(problem, options, name="refracture", monitors=[RefractureMonitor(t_off, t_on)])


def main(argv=None):
    parser = cli.scenario_parser("Re-fracturing under an on/off/on hydraulic load (paper §3.2)")
    parser.add_argument("--tau", type=float, default=30e-6, help="damage relaxation time tau~ [s]")
    parser.add_argument("--pump-rate", type=float, default=PUMP_RATE,
                        help="fluid pumped in while the load is on [m^2/s per m of thickness], flowing back out with "
                             "the removal; the load ends at the fluid's front (default %(default)s; inf: an unlimited "
                             "supply, the paper's pressure control)")
    cli.add_pressure_factor_argument(parser, "local", ": with 'connected' a crack beyond a part that closes first "
                                     "is cut off from the wellbore while the load is off and stays open, "
                                     "docs/studies/scenarios.md")
    # the network evolves (docs/model.md §6): microcracks nucleate where the bulk reaches the strength
    cli.add_growth_arguments(parser, nucleation_cap=NUCLEATION_CAP)
    cli.add_mesh_size_arguments(parser, "0.04, --quick 0.05", "0.8, --quick 0.5")
    cli.add_adapt_arguments(parser)
    cli.add_time_scheme_arguments(parser)
    histories = [geometry(q)[3] for q in (False, True)]  # (pressure, t_off, t_on, t_end), full and --quick
    args = cli.parse(parser, argv, name="refracture", degree=(2, 1), t_end=tuple(h[3] for h in histories),
                     frames=50)
    cli.check_growth_arguments(parser, args)
    cli.check_adapt_arguments(parser, args)
    _, t_off, t_on, _ = histories[args.quick]
    if not args.pump_rate > 0:
        parser.error(f"--pump-rate must be > 0 m^2/s (inf: unlimited); got {args.pump_rate}")
    cli.check_mesh_size_arguments(parser, args)
    cli.check_time_scheme_arguments(parser, args)
    params = dict(quick=args.quick, degree=args.degree, tau=args.tau, growth=wellbore.Growth.from_args(args),
                  connected=args.pressure_factor == "connected", pump_rate=args.pump_rate, adapt=args.adapt,
                  adapt_tol=args.adapt_tol, h_crack=args.h_crack, h_far=args.h_far, scheme=args.scheme, cfl=args.cfl)
    try:
        desc = description(**params)
    except ValueError as err:
        parser.error(str(err))
    r0 = desc.domain.wellbore_radius + desc.perforations[0].length
    if desc.growth is not None and desc.growth.max_radius is not None and not desc.growth.max_radius > r0:
        parser.error(f"--growth-max-radius {desc.growth.max_radius} m does not reach beyond the perforation tips "
                     f"({r0} m from the centre); make it larger")
    problem = setup(record=Path(args.out) / "growth.json", **params)
    return run(problem, cli.run_options(args, history_every=5), t_off, t_on)


if __name__ == "__main__":
    main()
