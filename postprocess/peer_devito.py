"""The Devito half of ``study_peer_devito``: the plane P wave on Devito's staggered-grid
velocity-stress scheme (the equations of Devito's ``examples/seismic/elastic``), float64,
one core.  Runs in an environment with Devito (``make devito-env``); it imports nothing of
hydrofrac, and reads its cases from, and writes its rows to, JSON files:

    python postprocess/peer_devito.py IN.json OUT.json

IN: {"direction": [dx, dy], "width": W, "travel": T, "rho", "lam", "mu", "cases": [[space_order,
N], ...], "repeats": 3}.  The time is Devito's own timer of its compiled time loop (the
strongest reading of the peer; ``apply_wall_s`` adds the Python call of ``Operator.apply``).  The unit square is padded by a ring of ``travel`` + 0.05 m (the
plane wave has no exact boundary condition in Devito's example; the ring keeps what the
padded edges do out of the unit square until the final time), and the error is the relative
energy norm over the unit square, each field on its own staggered points and times
(velocities half a step behind the stresses).  ``flops`` is Devito's own count of the
operator's flops (per grid point and step, times the points and steps).
"""
import json
import math
import os
import sys
import time

import numpy as np

os.environ.setdefault("DEVITO_LANGUAGE", "C")  # one core, no OpenMP
os.environ.setdefault("DEVITO_LOGGING", "WARNING")


def run(case, prm):
    from devito import (Eq, Grid, Operator, TensorTimeFunction, VectorTimeFunction, configuration, diag, div,
                        grad)
    # Devito's own count of the flops per grid point and step of the operator it generated
    # (after its common-subexpression and factorisation passes), read off the run's summary;
    # this level adds nothing to the compiled loop (its times are those of the basic level)
    configuration["profiling"] = "advanced"
    so, N = case
    d = np.array(prm["direction"])
    W, travel = prm["width"], prm["travel"]
    rho, lam, mu = prm["rho"], prm["lam"], prm["mu"]
    cd = math.sqrt((lam + 2 * mu) / rho)
    pad = travel + 0.05
    h = 1.0 / N
    n = int(round((1 + 2 * pad) / h)) + 1
    extent = (n - 1) * h
    grid = Grid(shape=(n, n), extent=(extent, extent), origin=(-pad, -pad), dtype=np.float64)
    v = VectorTimeFunction(name="v", grid=grid, space_order=so, time_order=1)
    tau = TensorTimeFunction(name="t", grid=grid, space_order=so, time_order=1)
    t_end = travel / cd
    steps = int(math.ceil(t_end / (0.5 * h / cd) - 1e-9))
    dt = t_end / steps
    eqs = [Eq(v.forward, v + dt / rho * div(tau)),
           # (transpose(inner=False): the plain .T of a Devito tensor also transposes its entries
           # and loses the 2 mu term on the diagonal, measured)
           Eq(tau.forward, tau + dt * lam * diag(div(v.forward))
              + dt * mu * (grad(v.forward) + grad(v.forward).transpose(inner=False)))]
    op = Operator(eqs)
    S = -(lam * np.eye(2) + 2 * mu * np.outer(d, d)) / cd

    def g(X, Y, t):
        xi = d[0] * (X - 0.5) + d[1] * (Y - 0.5) - cd * t
        return np.exp(-(xi / W) ** 2)

    x = -pad + h * np.arange(n)
    # staggered positions (Devito's defaults: v_x at x + h/2, v_y at y + h/2, diagonal stresses
    # on the nodes, the shear stress at (x + h/2, y + h/2))
    pos = {"vx": (x + h / 2, x), "vy": (x, x + h / 2), "txx": (x, x), "tyy": (x, x), "txy": (x + h / 2, x + h / 2)}

    def exact(name, t):
        X, Y = np.meshgrid(*pos[name], indexing="ij")
        gg = g(X, Y, t)
        return {"vx": d[0] * gg, "vy": d[1] * gg, "txx": S[0, 0] * gg, "tyy": S[1, 1] * gg, "txy": S[0, 1] * gg}[name]

    fields = {"vx": v[0], "vy": v[1], "txx": tau[0, 0], "tyy": tau[1, 1], "txy": tau[0, 1]}

    def initialise():
        for name, f in fields.items():
            f.data[:] = 0.0
            # stresses at t = 0; velocities at -dt/2 (leapfrog: v^{n+1} is at (n + 1/2) dt)
            f.data[0] = exact(name, -dt / 2 if name.startswith("v") else 0.0)

    walls, kernels = [], []
    for _ in range(prm.get("repeats", 3)):
        initialise()
        t0 = time.perf_counter()
        perf = op.apply(time_m=0, time_M=steps - 1, dt=dt)
        walls.append(time.perf_counter() - t0)
        kernels.append(sum(v.time for v in perf.values()))  # Devito's own timer of the compiled loop
    ops = sum(v.ops for v in perf.values())  # flops per grid point and step
    # the last stored level: stresses at steps*dt, velocities at (steps - 1/2) dt
    last = steps % 2
    kappa = lam / (2 * (lam + mu))
    num = den = 0.0
    inside = {k: ((p[0][:, None] >= 0) & (p[0][:, None] <= 1) & (p[1][None, :] >= 0) & (p[1][None, :] <= 1))
              for k, p in pos.items()}
    got = {k: np.asarray(f.data[last]) for k, f in fields.items()}
    ex = {k: exact(k, t_end - dt / 2 if k.startswith("v") else t_end) for k in fields}
    for k in ("vx", "vy"):
        num += rho * ((got[k] - ex[k]) ** 2)[inside[k]].sum()
        den += rho * (ex[k] ** 2)[inside[k]].sum()
    for k in ("txx", "tyy"):
        num += ((got[k] - ex[k]) ** 2)[inside[k]].sum() / (2 * mu)
        den += (ex[k] ** 2)[inside[k]].sum() / (2 * mu)
    dsum = (got["txx"] - ex["txx"] + got["tyy"] - ex["tyy"])[inside["txx"]]
    esum = (ex["txx"] + ex["tyy"])[inside["txx"]]
    num -= kappa * (dsum ** 2).sum() / (2 * mu)
    den -= kappa * (esum ** 2).sum() / (2 * mu)
    num += 2 * ((got["txy"] - ex["txy"]) ** 2)[inside["txy"]].sum() / (2 * mu)
    den += 2 * (ex["txy"] ** 2)[inside["txy"]].sum() / (2 * mu)
    unknowns = 5 * n * n
    return {"method": f"Devito SO{so}", "family": "Devito", "degree": so, "N": N, "dofs": unknowns,
            "unknowns_unit_square": 5 * (N + 1) ** 2, "steps": steps, "wall_s": min(kernels),
            "apply_wall_s": min(walls), "flops_per_unknown_step": ops / 5, "flops": ops * n * n * steps,
            "rel_error": math.sqrt(max(num, 0.0) / den)}


def main():
    prm = json.loads(open(sys.argv[1]).read())
    rows = [run(c, prm) for c in prm["cases"]]
    with open(sys.argv[2], "w") as f:
        json.dump(rows, f)


if __name__ == "__main__":
    main()
