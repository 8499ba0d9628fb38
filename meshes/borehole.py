"""Mesh of a pressurised borehole: a circular hole of radius ``a`` in a square
(half-size ``R``) or circular (radius ``R``) rock domain, centred at the origin.

The mesh is fine at the hole and coarsens linearly with the distance from it
(a Gmsh ``MathEval`` size field): ``h(r) = min(h_outer, h_hole + growth (r - a))``.
With ``quarter=True`` only the quadrant x, y >= 0 is meshed and the planes x = 0
and y = 0 are symmetry planes.

Physical groups, i.e. the values of the returned mesh tags (module constants):

====================  ===  =============================================
cells: ``ROCK``        1   the rock
``BOREHOLE``           1   borehole wall r = a
``OUTER``              2   outer boundary (square sides or circle r = R)
``SYMMETRY_X``         3   symmetry plane x = 0 (quarter model only)
``SYMMETRY_Y``         4   symmetry plane y = 0 (quarter model only)
====================  ===  =============================================
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Optional, Union

from mpi4py import MPI

from .gmsh_util import build_mesh

#: cell tag of the rock
ROCK = 1
#: facet tag of the borehole wall r = a
BOREHOLE = 1
#: facet tag of the outer boundary (square sides or circle r = R)
OUTER = 2
#: facet tag of the symmetry plane x = 0 (quarter model only; normal along x)
SYMMETRY_X = 3
#: facet tag of the symmetry plane y = 0 (quarter model only; normal along y)
SYMMETRY_Y = 4

SHAPES = ("square", "circle")


def _positive(name, value):
    if not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"borehole mesh: {name} must be a positive length in metres; got {value!r}")


def check_parameters(a, R, h_hole, h_outer, growth, shape):
    """Raise ValueError (saying what to change) for an impossible or badly resolved geometry."""
    _positive("a (borehole radius)", a)
    _positive("R (outer half-size)", R)
    if R <= 3 * a:
        raise ValueError(f"borehole mesh: the outer half-size R = {R} m must exceed 3 a = {3 * a} m "
                         f"(a = {a} m is the borehole radius); increase R or decrease a")
    _positive("h_hole (mesh size at the hole)", h_hole)
    _positive("h_outer (mesh size far from the hole)", h_outer)
    _positive("growth (mesh size increase per metre from the hole)", growth)
    if h_hole > a:
        raise ValueError(f"borehole mesh: h_hole = {h_hole} m is larger than the radius a = {a} m, so the hole "
                         f"would have fewer than ~6 edges; use h_hole <= a (a/4 is the default)")
    if h_outer < h_hole:
        raise ValueError(f"borehole mesh: h_outer = {h_outer} m must be >= h_hole = {h_hole} m")
    if h_outer > R / 2:
        raise ValueError(f"borehole mesh: h_outer = {h_outer} m must be <= R/2 = {R / 2} m")
    if shape not in SHAPES:
        raise ValueError(f"borehole mesh: shape must be one of {SHAPES}; got {shape!r}")


def _geometry(model, a, R, h_hole, h_outer, growth, quarter, shape):
    """Gmsh callback: OCC geometry, curve classification, physical groups and size field."""
    import gmsh

    occ = model.occ
    if shape == "square":
        outer = occ.addRectangle(0, 0, 0, R, R) if quarter else occ.addRectangle(-R, -R, 0, 2 * R, 2 * R)
    else:
        outer = occ.addDisk(0, 0, 0, R, R)
        if quarter:
            box = occ.addRectangle(0, 0, 0, R, R)
            (outer_dt, _) = occ.intersect([(2, outer)], [(2, box)])
            outer = outer_dt[0][1]
    hole = occ.addDisk(0, 0, 0, a, a)
    surfaces, _ = occ.cut([(2, outer)], [(2, hole)])
    occ.synchronize()

    tol = 1e-6 * R
    groups = {BOREHOLE: [], OUTER: [], SYMMETRY_X: [], SYMMETRY_Y: []}
    for dim, tag in model.getEntities(1):
        x0, y0, _, x1, y1, _ = model.getBoundingBox(dim, tag)
        if quarter and abs(x0) < tol and abs(x1) < tol:
            groups[SYMMETRY_X].append(tag)
        elif quarter and abs(y0) < tol and abs(y1) < tol:
            groups[SYMMETRY_Y].append(tag)
        elif max(abs(x0), abs(x1), abs(y0), abs(y1)) < a + tol:
            groups[BOREHOLE].append(tag)
        else:
            groups[OUTER].append(tag)
    if not groups[BOREHOLE] or not groups[OUTER] or (quarter and not (groups[SYMMETRY_X] and groups[SYMMETRY_Y])):
        raise RuntimeError(f"could not identify the boundary curves: {groups}")
    model.addPhysicalGroup(2, [s[1] for s in surfaces], ROCK)
    for tag, curves in groups.items():
        if curves:
            model.addPhysicalGroup(1, curves, tag)

    field = model.mesh.field.add("MathEval")
    model.mesh.field.setString(field, "F", f"min({h_outer!r}, {h_hole!r} + {growth!r} * (sqrt(x*x + y*y) - {a!r}))")
    model.mesh.field.setAsBackgroundMesh(field)
    for opt in ("MeshSizeExtendFromBoundary", "MeshSizeFromPoints", "MeshSizeFromCurvature"):
        gmsh.option.setNumber(f"Mesh.{opt}", 0)


def borehole_mesh(comm: MPI.Comm = MPI.COMM_WORLD, a: float = 0.1, R: float = 2.0, h_hole: Optional[float] = None,
                  h_outer: Optional[float] = None, growth: float = 0.25, quarter: bool = False,
                  shape: str = "square", out: Optional[Union[str, Path]] = None):
    """Triangle mesh of the rock around a borehole.

    Parameters
    ----------
    comm : MPI communicator
    a : borehole radius [m], > 0
    R : outer half-size (square) or radius (circle) [m], > 3a
    h_hole : mesh size at the borehole wall [m] (default a/4)
    h_outer : largest mesh size, reached far from the hole [m] (default R/10)
    growth : increase of the mesh size per metre of distance from the hole
    quarter : mesh the quadrant x, y >= 0 only (symmetry planes x = 0, y = 0)
    shape : "square" or "circle" outer boundary
    out : where to save the geometry if Gmsh fails

    Returns
    -------
    (mesh, cell_tags, facet_tags) with the tags of this module (:data:`BOREHOLE`, ...)
    """
    h_hole = a / 4 if h_hole is None else h_hole
    h_outer = R / 10 if h_outer is None else h_outer
    check_parameters(a, R, h_hole, h_outer, growth, shape)
    name = f"borehole_{shape}{'_quarter' if quarter else ''}"
    return build_mesh(comm, lambda model: _geometry(model, a, R, h_hole, h_outer, growth, quarter, shape),
                      name=name, out=out)
