"""Output that ParaView opens: VTK XML pieces per rank, one ``.pvd`` time series.

DOLFINx 0.5's XDMF output of DG fields opens empty in ParaView 5.11, so
hydrofrac writes its own files: every rank writes a binary ``.vtu`` piece, rank 0
a ``.pvtu`` per part and the ``.pvd`` collection, rewritten (atomically) after
every frame so the series on disk is always complete.  A frame may hold several
parts (the bulk DG fields and the crack-interface line mesh); ParaView shows
them as the blocks of one multiblock time series.  A frame that any rank cannot write
is the same :class:`OutputError` on every rank (:func:`failures`), never a rank waiting
for one that has stopped.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Dict, Optional

import numpy as np

VTK_TRIANGLE = 5
VTK_LINE = 3
VTK_LAGRANGE_TRIANGLE = 69

class OutputError(RuntimeError):
    """Output that could not be written (a full disk, a folder without write permission)."""


def failures(comm, action):
    """Run ``action`` on this rank and return every rank's error (as "rank r: Type: message";
    empty: it worked everywhere), on every rank: collective (one allgather), so that the
    ranks decide together whether to go on."""
    try:
        action()
        err = None
    except Exception as e:  # (reported on every rank)
        err = f"rank {comm.rank}: {type(e).__name__}: {e}"
    return [e for e in comm.allgather(err) if e is not None]


_TYPES = {np.dtype(np.float64): "Float64", np.dtype(np.float32): "Float32", np.dtype(np.int32): "Int32",
          np.dtype(np.int64): "Int64", np.dtype(np.uint8): "UInt8"}


def lagrange_lattice(p: int) -> np.ndarray:
    """Equispaced points of a degree-p triangle in VTK Lagrange order (p <= 4)."""
    if p == 1:
        return np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    pts = [(0, 0), (p, 0), (0, p)]
    pts += [(i, 0) for i in range(1, p)]
    pts += [(p - i, i) for i in range(1, p)]
    pts += [(0, p - i) for i in range(1, p)]
    if p == 3:
        pts += [(1, 1)]
    elif p == 4:
        pts += [(1, 1), (2, 1), (1, 2)]
    elif p > 4:
        raise ValueError("VTK output supports p <= 4")
    return np.array(pts, dtype=float) / p


class _Appended:
    """The arrays of one ``.vtu`` piece as raw appended data: each DataArray element names its
    offset into one binary block after the XML (a UInt64 byte count, then the bytes), so no
    array is encoded as text (base64 took most of a frame's time)."""

    def __init__(self):
        self.blocks, self.offset = [], 0

    def array(self, name, arr):
        arr = np.asarray(arr)
        if arr.dtype not in _TYPES:
            arr = arr.astype(np.float64)
        ncomp = 1 if arr.ndim == 1 else arr.shape[1]
        raw = np.ascontiguousarray(arr).tobytes()
        self.blocks += [np.array([len(raw)], dtype=np.uint64).tobytes(), raw]
        xml = (f'<DataArray type="{_TYPES[arr.dtype]}" Name="{name}" NumberOfComponents="{ncomp}" '
               f'format="appended" offset="{self.offset}"/>\n')
        self.offset += 8 + len(raw)
        return xml


def write_vtu(path, points, cells, cell_type, point_data=None, cell_data=None):
    """One unstructured-grid piece: points (m, 2|3), cells (k, nodes per cell)."""
    points = np.asarray(points, dtype=np.float64)
    if points.shape[1] == 2:
        points = np.hstack([points, np.zeros((points.shape[0], 1))])
    cells = np.asarray(cells, dtype=np.int64)
    k, npc = cells.shape if cells.size else (0, 1)
    a = _Appended()
    out = ['<?xml version="1.0"?>\n<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" '
           'header_type="UInt64">\n<UnstructuredGrid>\n',
           f'<Piece NumberOfPoints="{points.shape[0]}" NumberOfCells="{k}">\n<Points>\n',
           a.array("Points", points), "</Points>\n<Cells>\n",
           a.array("connectivity", cells.reshape(-1)),
           a.array("offsets", np.arange(1, k + 1, dtype=np.int64) * npc),
           a.array("types", np.full(k, cell_type, dtype=np.uint8)), "</Cells>\n<PointData>\n"]
    for name, arr in (point_data or {}).items():
        out.append(a.array(name, arr))
    out.append("</PointData>\n<CellData>\n")
    for name, arr in (cell_data or {}).items():
        out.append(a.array(name, arr))
    out.append('</CellData>\n</Piece>\n</UnstructuredGrid>\n<AppendedData encoding="raw">\n_')
    _atomic_write(path, ["".join(out).encode()] + a.blocks + [b"\n</AppendedData>\n</VTKFile>\n"])


def _pdata(tag, data):
    out = [f"<{tag}>\n"]
    for name, arr in data.items():
        arr = np.asarray(arr)
        dt = _TYPES.get(arr.dtype, "Float64")
        ncomp = 1 if arr.ndim == 1 else arr.shape[1]
        out.append(f'<PDataArray type="{dt}" Name="{name}" NumberOfComponents="{ncomp}"/>\n')
    out.append(f"</{tag}>\n")
    return "".join(out)


def _atomic_write(path, content):
    """Write ``content`` (text, or a list of byte strings) to ``path`` through a temporary file
    and a rename, so that ``path`` is always whole."""
    tmp = f"{path}.tmp{os.getpid()}"
    if isinstance(content, str):
        with open(tmp, "w") as f:
            f.write(content)
    else:
        with open(tmp, "wb") as f:
            for chunk in content:
                f.write(chunk)
    os.replace(tmp, path)


class Part:
    """What one part of a frame contains on this rank."""

    def __init__(self, points, cells, cell_type, point_data=None, cell_data=None):
        self.points, self.cells, self.cell_type = points, cells, cell_type
        self.point_data = point_data or {}
        self.cell_data = cell_data or {}


class VTKSeries:
    """A ``.pvd`` time series of one or more parts, written as it goes.

    ``series.write(t, {"bulk": Part(...), "cracks": Part(...)})`` must be called
    collectively; every rank passes its own piece of each part (possibly empty).
    """

    def __init__(self, out_dir, name, comm):
        self.dir = Path(out_dir)
        self.name = name
        self.comm = comm
        self.frames = []  # (t, {part: pvtu file})
        if comm.rank == 0:
            (self.dir / "vtk").mkdir(parents=True, exist_ok=True)
        comm.barrier()

    @property
    def pvd_path(self):
        return self.dir / f"{self.name}.pvd"

    def write(self, t: float, parts: Dict[str, Part]):
        """Write frame ``t`` (collective; :class:`OutputError` on every rank if any rank
        cannot write its piece, or rank 0 the collection)."""
        i = len(self.frames)
        files = {pname: f"vtk/{self.name}_{pname}_{i:05d}.pvtu" for pname in parts}

        def write():
            for pname, part in parts.items():
                base = f"{self.name}_{pname}_{i:05d}"
                piece = f"{base}_r{self.comm.rank}.vtu"
                write_vtu(self.dir / "vtk" / piece, part.points, part.cells, part.cell_type,
                          part.point_data, part.cell_data)
                if self.comm.rank == 0:
                    pieces = "".join(f'<Piece Source="{base}_r{r}.vtu"/>\n' for r in range(self.comm.size))
                    text = ('<?xml version="1.0"?>\n<VTKFile type="PUnstructuredGrid" version="1.0" '
                            'byte_order="LittleEndian" header_type="UInt64">\n<PUnstructuredGrid GhostLevel="0">\n'
                            '<PPoints><PDataArray type="Float64" NumberOfComponents="3"/></PPoints>\n'
                            + _pdata("PPointData", part.point_data) + _pdata("PCellData", part.cell_data)
                            + pieces + "</PUnstructuredGrid>\n</VTKFile>\n")
                    _atomic_write(self.dir / "vtk" / f"{base}.pvtu", text)
            if self.comm.rank == 0:
                self._write_pvd(self.frames + [(t, files)])

        errors = failures(self.comm, write)
        if errors:
            raise OutputError(f"could not write frame {i} (t = {t:.6g} s) of {self.pvd_path}: {'; '.join(errors)}. "
                              "The frames before it are complete; free disk space or choose a writable --out")
        self.frames.append((t, files))

    def _write_pvd(self, frames):
        names = []
        for _, files in frames:
            for p in files:
                if p not in names:
                    names.append(p)
        lines = ['<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
                 "<Collection>\n"]
        for t, files in frames:
            for p, f in files.items():
                lines.append(f'<DataSet timestep="{t:.9e}" group="" part="{names.index(p)}" name="{p}" file="{f}"/>\n')
        lines.append("</Collection>\n</VTKFile>\n")
        _atomic_write(self.pvd_path, "".join(lines))

    def restore(self, frames):
        """Continue a series after a restart (frames from the checkpoint)."""
        self.frames = [(float(t), dict(f)) for t, f in frames]


def bulk_part(solver, extra: Optional[Dict[str, np.ndarray]] = None) -> Part:
    """The DG fields of ``solver`` on its owned cells, sampled at the equispaced lattice.

    Point data: velocity, stress (symmetric tensor, with the plane-strain s_zz), the
    strain- and kinetic-energy densities relative to the initial stress; cell data:
    material index and MPI rank.
    """
    from . import compat
    from .material import plane_strain_kappa
    p = solver.degree
    nloc = compat.num_cells_local(solver.mesh)
    X = lagrange_lattice(p)
    T = solver.ref.tabulate(X)  # (npc, n)
    dofs = compat.cell_dofs(solver.V)[:nloc]
    U = compat.function_array_of_vec(solver.x).reshape(-1, 5)[dofs]  # (nloc, n, 5)
    vals = np.einsum("pn,cnk->cpk", T, U).reshape(-1, 5)
    g = solver.geometry
    pts = (g.x0[:nloc, None, :] + np.einsum("cij,pj->cpi", g.J[:nloc], X)).reshape(-1, 2)
    npc = X.shape[0]
    cells = np.arange(nloc * npc).reshape(nloc, npc)
    cell_type = VTK_TRIANGLE if p == 1 else VTK_LAGRANGE_TRIANGLE
    cm = np.repeat(np.arange(nloc), npc)
    rho, lam, mu = solver.rho_cell[cm], solver.lam_cell[cm], solver.mu_cell[cm]
    s0 = solver.sigma0
    v = vals[:, :2]
    sxx, syy, sxy = vals[:, 2], vals[:, 3], vals[:, 4]
    kappa = plane_strain_kappa(lam, mu)
    szz = kappa * (sxx + syy)
    dxx, dyy, dxy = sxx - s0[0, 0], syy - s0[1, 1], sxy - s0[0, 1]
    w_strain = 0.5 / (2 * mu) * (dxx ** 2 + dyy ** 2 + 2 * dxy ** 2 - kappa * (dxx + dyy) ** 2)
    w_kin = 0.5 * rho * (v ** 2).sum(axis=1)
    pd = {
        "velocity": np.hstack([v, np.zeros((v.shape[0], 1))]),
        "stress": np.stack([sxx, syy, szz, sxy, np.zeros_like(sxx), np.zeros_like(sxx)], axis=1),
        "strain_energy_density": w_strain,
        "kinetic_energy_density": w_kin,
    }
    if extra:
        pd.update(extra)
    cd = {"material": solver.cell_material[:nloc].astype(np.int32),
          "rank": np.full(nloc, solver.comm.rank, dtype=np.int32)}
    return Part(pts, cells, cell_type, pd, cd)
