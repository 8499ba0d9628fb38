"""Build a DOLFINx mesh from a Gmsh geometry, on any number of MPI ranks.

Gmsh runs on rank 0 only: a geometry callback adds the entities and physical
groups to the Gmsh model, Gmsh meshes it, and
:func:`hydrofrac.compat.gmsh_model_to_mesh` distributes the triangles (with the
facet ghosts the DG solver needs) and the physical groups as cell and facet
tags (:func:`build_mesh`); or the mesh is captured as arrays on rank 0 (:func:`mesh_arrays`)
for :func:`hydrofrac.compat.mesh_from_arrays`.  If Gmsh fails, every rank raises the same :class:`RuntimeError`, and the
geometry is saved next to the output so it can be opened with ``gmsh <file>``.
"""
from __future__ import annotations

import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Optional, Union

from mpi4py import MPI

from hydrofrac import compat


def _save_failed_geometry(gmsh, out: Optional[Union[str, Path]]) -> str:
    """Write the current Gmsh model for inspection; returns where it went (or why not)."""
    folder = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="hydrofrac_gmsh_"))
    folder.mkdir(parents=True, exist_ok=True)
    for ext in ("brep", "geo_unrolled"):  # brep first: writing .geo_unrolled after a failed size field crashes Gmsh 4.8
        path = folder / f"failed_geometry.{ext}"
        try:
            gmsh.write(str(path))
            return str(path)
        except Exception:  # noqa: BLE001 - try the next format
            continue
    return f"(could not be saved in {folder})"


def _gmsh_errors(gmsh):
    """The last error lines of Gmsh's log (it does not always raise on an error)."""
    try:
        lines = [line for line in gmsh.logger.get() if line.startswith("Error")]
    except Exception:  # noqa: BLE001 - the log is a courtesy
        return ""
    return (" Gmsh said: " + " | ".join(lines[-3:])) if lines else ""


def _mesh_on_root(gmsh, name, build, mesh_dim, out, verbose):
    """Rank 0: run the callback and mesh; returns an error message or None."""
    gmsh.logger.start()
    try:
        return _geometry_and_mesh(gmsh, name, build, mesh_dim, out, verbose)
    finally:
        gmsh.logger.stop()


def _geometry_and_mesh(gmsh, name, build, mesh_dim, out, verbose):
    try:
        gmsh.option.setNumber("General.Terminal", 1 if verbose else 0)
        gmsh.model.add(name)
        build(gmsh.model)
        if not gmsh.model.getPhysicalGroups(mesh_dim):
            raise ValueError(f"the geometry callback defined no physical group of dimension {mesh_dim}; "
                             f"add one with gmsh.model.addPhysicalGroup({mesh_dim}, [...], tag) so the "
                             "cells are kept and tagged")
    except Exception as err:  # noqa: BLE001 - reported to every rank by build_mesh
        where = _save_failed_geometry(gmsh, out)
        return (f"building the Gmsh geometry '{name}' failed: {err}.{_gmsh_errors(gmsh)} Fix the geometry "
                f"callback (closed curve loops, valid boolean operations, physical groups); the partial "
                f"geometry is saved in {where}")
    try:
        gmsh.model.mesh.generate(mesh_dim)
        _, tags, _ = gmsh.model.mesh.getElements(mesh_dim)
        if sum(len(t) for t in tags) == 0:
            raise RuntimeError("Gmsh produced no elements")
    except Exception as err:  # noqa: BLE001 - reported to every rank by build_mesh
        where = _save_failed_geometry(gmsh, out)
        return (f"Gmsh could not mesh '{name}': {err}.{_gmsh_errors(gmsh)} Check that the mesh sizes are "
                f"positive and well below the size of the geometry, and that curves do not overlap or "
                f"self-intersect; the geometry is saved in {where} (open it with `gmsh {where}`)")
    return None


def build_mesh(comm: MPI.Comm, build: Callable, name: str = "model", out: Optional[Union[str, Path]] = None,
               gdim: int = 2, verbose: bool = False):
    """Mesh a Gmsh geometry on rank 0 and distribute it over ``comm``.

    Parameters
    ----------
    comm : MPI communicator of the mesh
    build : ``build(model)`` adds the geometry to the ``gmsh.model`` it is given,
        synchronises it, sets the mesh sizes and adds the physical groups (cells:
        dimension ``gdim``, facets: ``gdim - 1``); it runs on rank 0 only
    name : model name (messages, saved geometry)
    out : folder for ``failed_geometry.geo_unrolled`` if Gmsh fails (default: a
        fresh temporary folder)
    gdim : geometric (and mesh) dimension
    verbose : show Gmsh's own log

    Returns
    -------
    (mesh, cell_tags, facet_tags) : the physical groups of dimension ``gdim`` and
    ``gdim - 1`` as DOLFINx mesh tags

    Raises
    ------
    RuntimeError on every rank if the geometry or the meshing fails.
    """
    return _meshed(comm, build, name, out, gdim, verbose,
                   lambda gmsh: compat.gmsh_model_to_mesh(gmsh.model, comm, rank=0, gdim=gdim))


def _meshed(comm, build, name, out, gdim, verbose, then):
    """``then(gmsh)`` on every rank after rank 0 meshed ``build``'s geometry (the model
    removed after it); RuntimeError on every rank if the geometry or the meshing fails."""
    with gmsh_session(comm) as gmsh:
        error = _mesh_on_root(gmsh, name, build, gdim, out, verbose) if comm.rank == 0 else None
        error = comm.bcast(error, root=0)
        try:
            if error is not None:
                raise RuntimeError(error)
            return then(gmsh)
        finally:
            if comm.rank == 0:
                gmsh.model.remove()


@contextmanager
def gmsh_session(comm: MPI.Comm):
    """The gmsh module, started on rank 0 for the block unless it runs already (then it is
    finished here too; Gmsh < 4.9 has no isInitialized(): there, always started here)."""
    import gmsh
    started = comm.rank == 0 and not getattr(gmsh, "isInitialized", lambda: False)()
    if started:
        gmsh.initialize()
    try:
        yield gmsh
    finally:
        if started:
            gmsh.finalize()


def mesh_arrays(comm: MPI.Comm, build: Callable, capture: Callable, name: str = "model",
                out: Optional[Union[str, Path]] = None, gdim: int = 2, verbose: bool = False):
    """Mesh a Gmsh geometry on rank 0 as :func:`build_mesh` does, and return what
    ``capture(gmsh)`` makes of the mesh there (e.g. :func:`hydrofrac.meshes.patch.capture`'s
    arrays; None on the other ranks), for :func:`hydrofrac.compat.mesh_from_arrays` to
    distribute without reading the Gmsh model again.  Raises RuntimeError on every rank if the
    geometry or the meshing fails."""
    return _meshed(comm, build, name, out, gdim, verbose, lambda gmsh: capture(gmsh) if comm.rank == 0 else None)
