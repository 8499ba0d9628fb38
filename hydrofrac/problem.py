"""The problem object: one owner of a mesh's solver, crack interface, hydraulics and network.

A scenario describes a problem; :class:`Problem` owns what is built from the description
on one mesh, and :func:`hydrofrac.run.run` drives it.  Nothing outside the problem wires its
parts together, and nothing outside the time loop updates its physics:

* the interface (:class:`~hydrofrac.interface.Interface`) is attached to the solver as its
  crack extension here;
* the hydraulic load (:class:`~hydrofrac.hydraulics.Hydraulics`) becomes the interface's
  separation law here, and :meth:`Problem.after_step` updates the network and the pressure
  factor after every step (the loop calls it);
* remeshing (:class:`~hydrofrac.growth.GrowthDriver`) makes a new problem from a new
  geometry and moves the state onto it; monitors receive the current problem.
"""
from __future__ import annotations

import time
from typing import Dict, Optional

from .hydraulics import HydraulicParams, Hydraulics
from .io import bulk_part
from .network import CrackNetwork


class Problem:
    """A built problem on one mesh.

    Parameters
    ----------
    solver : :class:`~hydrofrac.solver.Solver` (bulk operator, boundary data, time stepping)
    interface : crack interface on the solver's mesh, or None (no cracks)
    hydraulics : :class:`~hydrofrac.hydraulics.HydraulicParams` of a hydraulic load on the
        cracks, or None (traction-free separation)
    network : the cracks' geometry (:class:`~hydrofrac.network.CrackNetwork`), or None
    facet_tags : the mesh's facet tags (crack and boundary markers)
    """

    def __init__(self, solver, interface=None, hydraulics: Optional[HydraulicParams] = None,
                 network: Optional[CrackNetwork] = None, facet_tags=None):
        self.solver = solver
        self.interface = interface
        self.network = network
        self.facet_tags = facet_tags
        self.growth = None  # the growth driver that rebuilds this problem (set by it)
        self.hydraulics = None
        if interface is not None:
            if interface.solver is not solver:
                raise ValueError("the interface was built on another solver than the problem's")
            solver.attach(interface)
        if hydraulics is not None:
            if interface is None:
                raise ValueError("a hydraulic load needs cracks: give the problem an interface")
            self.hydraulics = Hydraulics(interface, hydraulics)
            interface.set_separation_law(self.hydraulics.separation_traction)

    # ------------------------------------------------------------------ what the loop calls
    @property
    def comm(self):
        return self.solver.comm

    @property
    def mesh(self):
        return self.solver.mesh

    @property
    def t(self) -> float:
        return self.solver.t

    def after_step(self):
        """Everything that follows a step outside the RK stages: the hydraulic network and
        the pressure factor (docs/model.md §5: they lag the stages by at most one step)."""
        if self.hydraulics is not None:
            t0 = time.perf_counter()
            self.hydraulics.update()
            self.solver.timers.add("hydraulics", time.perf_counter() - t0)

    def after_restore(self):
        """The derived state after the interface state was set (checkpoint, transfer)."""
        if self.hydraulics is not None:
            self.hydraulics.update()

    def release(self):
        """Free the PETSc objects of this problem (:meth:`hydrofrac.solver.Solver.release`) once
        a remesh has replaced it; collective."""
        return self.solver.release()

    def parts(self) -> Dict:
        """Output parts of one frame: the bulk fields and, with cracks, the crack line mesh
        (interface fields plus the hydraulic ones)."""
        p = {"bulk": bulk_part(self.solver)}
        if self.interface is not None:
            p.update(self.interface.part(self.hydraulics.fields() if self.hydraulics is not None else None))
        return p

    def probe(self, points):
        """(m, 5): v_x, v_y, s_xx, s_yy, s_xy at physical points (m, 2) (collective;
        :func:`hydrofrac.probes.field_at`)."""
        from .probes import field_at
        return field_at(self.solver, points)

    def crack_probe(self, positions):
        """(m, 7): opening, slip, tractions, D, eta, f_p at (crack tag, arc length) positions
        (collective; :func:`hydrofrac.probes.crack_at`)."""
        from .probes import crack_at
        return crack_at(self, positions)

    def summary(self) -> Dict:
        out = self.solver.summary()
        if self.interface is not None:
            out["contact"] = self.interface.contact_report()
        if self.network is not None:
            out["network"] = self.network.counts()
        return out
