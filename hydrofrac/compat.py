"""Every DOLFINx-version-specific call of hydrofrac lives here (DOLFINx 0.5.2).

Porting to DOLFINx 0.9+ means changing this file: the rest of the package
talks to meshes, function spaces, forms and PETSc objects only through these
helpers (plus plain numpy arrays).  Notes for the port are next to each call.
"""
from __future__ import annotations

import logging

import numpy as np
import ufl
from mpi4py import MPI

import dolfinx
import dolfinx.fem
import dolfinx.fem.petsc
import dolfinx.graph
import dolfinx.jit
import dolfinx.mesh



class _BelowWarning(logging.Filter):
    def filter(self, record):
        return record.levelno >= logging.WARNING


_QUIET = _BelowWarning()


def quiet_form_compiler(quiet: bool = True):
    """Hide (or show, ``quiet=False``) the INFO lines of the form compiler's JIT: FFCx and
    the C build it drives (setuptools resets the root logger to INFO at every compile, so
    the filter sits on the handlers)."""
    import ffcx  # noqa: F401  (installs the root handler that the JIT logs to)
    root = logging.getLogger()
    for h in root.handlers:
        (h.addFilter if quiet else h.removeFilter)(_QUIET)
    for name in ("ffcx", "UFL", "ufl"):
        logging.getLogger(name).setLevel(logging.WARNING if quiet else logging.INFO)


quiet_form_compiler(True)

DOLFINX_VERSION = dolfinx.__version__
GHOST_MODE = dolfinx.mesh.GhostMode.shared_facet  # DG needs the neighbour cell across every facet


# --- meshes -----------------------------------------------------------------
def create_rectangle(comm, p0, p1, nx, ny, diagonal="right"):
    """Structured triangle mesh of [p0, p1] with facet ghosts (0.9: same name)."""
    diag = {"right": dolfinx.mesh.DiagonalType.right, "crossed": dolfinx.mesh.DiagonalType.crossed,
            "left": dolfinx.mesh.DiagonalType.left}[diagonal]
    return dolfinx.mesh.create_rectangle(comm, [np.asarray(p0, float), np.asarray(p1, float)], [nx, ny],
                                         dolfinx.mesh.CellType.triangle, GHOST_MODE, diagonal=diag)


def _ordered_partition(comm, nparts, graph, ghosting):
    """A deterministic graph partition: the dual graph (all on one rank, as Gmsh's mesh comes)
    in reverse Cuthill-McKee order, cut into ``nparts`` equal slabs; with ``ghosting`` every
    cell also goes to the ranks of its facet neighbours.  SCOTCH's partition of the same
    mesh differs from one call to the next in a process, so a rebuilt mesh (a restart of a
    remeshing run) would not be the one the checkpoint was written on."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee
    from dolfinx.cpp.graph import AdjacencyList_int32
    n = graph.num_nodes
    offsets = np.asarray(graph.offsets)
    if n == 0:
        return AdjacencyList_int32(np.zeros(0, np.int32), np.zeros(1, np.int32))
    nbr = np.asarray(graph.array)
    rows = np.repeat(np.arange(n), np.diff(offsets))
    if nbr.size and nbr.max() >= n:  # the graph is not all here: leave it to SCOTCH
        return dolfinx.graph.partitioner_scotch()(comm, nparts, graph, ghosting)
    A = sp.csr_matrix((np.ones(nbr.size), (rows, nbr)), shape=(n, n))
    order = reverse_cuthill_mckee(A, symmetric_mode=True)
    owner = np.empty(n, np.int32)
    owner[order] = (np.arange(n) * nparts // n).astype(np.int32)
    if not ghosting or nparts == 1:
        return AdjacencyList_int32(owner, np.arange(n + 1, dtype=np.int32))
    return _with_ghosts(owner, rows, owner[nbr], nparts)


def gmsh_model_to_mesh(model, comm, rank=0, gdim=2):
    """Gmsh model (on ``rank``) -> (mesh, cell_tags, facet_tags), distributed by
    :func:`_ordered_partition` (0.9: ``gmshio.model_to_mesh`` returns the same triple and takes
    the partitioner as an argument)."""
    import functools
    from dolfinx.io import gmshio
    partitioner = dolfinx.mesh.create_cell_partitioner(_ordered_partition)
    default = gmshio.create_mesh
    gmshio.create_mesh = functools.partial(dolfinx.mesh.create_mesh, partitioner=partitioner)
    try:
        return gmshio.model_to_mesh(model, comm, rank, gdim=gdim)
    finally:
        gmshio.create_mesh = default


def mesh_from_arrays(comm, nodes, cells, cell_tag, facets, facet_values, rank=0, gdim=2):
    """A triangle mesh that ``rank`` holds as arrays -> (mesh, cell_tags, facet_tags), distributed
    by :func:`_ordered_partition`: ``nodes`` (n, >= gdim), ``cells`` (m, 3) node indices, every cell
    tagged ``cell_tag``, ``facets`` (k, 2) node pairs tagged ``facet_values`` (k,); the other ranks
    pass empty arrays.  The same mesh and tags as :func:`gmsh_model_to_mesh` of a Gmsh model with
    these nodes (by tag), triangles and lines, without building or reading one (0.9:
    ``dolfinx.mesh.create_mesh`` takes the partitioner and the element; the tags the same way)."""
    here = comm.rank == rank
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3) if here else np.zeros((0, 3), np.int64)
    x = np.ascontiguousarray(np.asarray(nodes, dtype=float)[:, :gdim]) if here else np.zeros((0, gdim))
    facets = np.asarray(facets, dtype=np.int64).reshape(-1, 2) if here else np.zeros((0, 2), np.int64)
    facet_values = np.asarray(facet_values, dtype=np.int32) if here else np.zeros(0, np.int32)
    return _mesh_and_tags(comm, cells, x, cell_tag, facets, facet_values, _ordered_partition, gdim)


def _mesh_and_tags(comm, cells, x, cell_tag, facets, facet_values, partition, gdim):
    """DOLFINx's mesh of this rank's ``cells`` and nodes ``x``, distributed by ``partition``, with
    every cell tagged ``cell_tag`` and the ``facets`` tagged ``facet_values``."""
    from dolfinx.io.gmshio import ufl_mesh
    from dolfinx.cpp.graph import AdjacencyList_int32, AdjacencyList_int64
    domain = ufl_mesh(2, gdim)  # Gmsh's element type 2: the 3-node triangle (its node order is DOLFINx's)
    # the cells as an adjacency list: 0.5's create_mesh tries a 2D array first, and its failed
    # overload formats both arrays into the TypeError (about 1 ms a remesh) before it retries so
    mesh = dolfinx.mesh.create_mesh(comm, AdjacencyList_int64(np.ascontiguousarray(cells, dtype=np.int64)), x, domain,
                                    ghost_mode=GHOST_MODE,
                                    partitioner=dolfinx.mesh.create_cell_partitioner(partition))
    tdim = mesh.topology.dim
    # every cell has the one tag: each rank tags its cells, ghosts included (what distributing
    # the tag of every input cell gives, without the exchange)
    imap = mesh.topology.index_map(tdim)
    n = imap.size_local + imap.num_ghosts
    ct = dolfinx.mesh.meshtags(mesh, tdim, np.arange(n, dtype=np.int32), np.full(n, cell_tag, np.int32))
    ct.name = "Cell tags"
    ent, val = dolfinx.cpp.io.distribute_entity_data(mesh._mesh, tdim - 1, facets, facet_values)
    mesh.topology.create_connectivity(tdim - 1, tdim)
    ft = dolfinx.mesh.meshtags_from_entities(mesh, tdim - 1, AdjacencyList_int32(ent), val.astype(np.int32))
    ft.name = "Facet tags"
    return mesh, ct, ft


def _keep_partition(comm, nparts, graph, ghosting):
    """Every cell stays on the rank that passed it to ``create_mesh``; with ``ghosting`` it also
    goes to the ranks of its facet neighbours.  The dual graph is distributed: its nodes are
    numbered by rank, each rank's cells after the cells of the ranks before it."""
    from dolfinx.cpp.graph import AdjacencyList_int32
    n = graph.num_nodes
    start = np.cumsum([0] + comm.allgather(n))
    owner = np.full(n, comm.rank, np.int32)
    if not ghosting or nparts == 1 or n == 0:
        return AdjacencyList_int32(owner, np.arange(n + 1, dtype=np.int32))
    offsets = np.asarray(graph.offsets)
    nbr = np.asarray(graph.array, dtype=np.int64)
    rows = np.repeat(np.arange(n), np.diff(offsets))
    return _with_ghosts(owner, rows, (np.searchsorted(start, nbr, side="right") - 1).astype(np.int32), nparts)


def _with_ghosts(owner, rows, other, nparts):
    """Each cell's destinations: its ``owner`` first, then the other owners of its neighbours
    (``other``: the owner of the neighbour of each edge ``rows`` -> neighbour) in increasing order."""
    from dolfinx.cpp.graph import AdjacencyList_int32
    n = owner.size
    ghost = other != owner[rows]
    pairs = np.unique(rows[ghost].astype(np.int64) * nparts + other[ghost])
    cell = np.r_[np.arange(n, dtype=np.int64), pairs // nparts]
    rank = np.r_[owner, (pairs % nparts).astype(np.int32)]
    order = np.argsort(cell, kind="stable")  # the owners (first n entries) stay ahead of their ghosts
    lengths = np.bincount(cell, minlength=n)
    return AdjacencyList_int32(rank[order].astype(np.int32), np.r_[0, np.cumsum(lengths)].astype(np.int32))


def _owners_partition(owners):
    """A partition that sends each cell this rank passes to ``create_mesh`` to the rank
    ``owners`` gives it (in the order passed); with ``ghosting`` it also goes to the ranks of its
    facet neighbours, whose owners are asked of the ranks that passed them."""
    def partition(comm, nparts, graph, ghosting):
        from dolfinx.cpp.graph import AdjacencyList_int32
        n = graph.num_nodes
        owner = np.asarray(owners, dtype=np.int32).reshape(-1)
        if owner.size != n:
            raise RuntimeError(f"{owner.size} owners for {n} cells")
        if not ghosting or nparts == 1:
            return AdjacencyList_int32(owner, np.arange(n + 1, dtype=np.int32))
        start = np.cumsum([0] + comm.allgather(n))
        nbr = np.asarray(graph.array, dtype=np.int64)
        rows = np.repeat(np.arange(n), np.diff(np.asarray(graph.offsets)))
        src = np.searchsorted(start, nbr, side="right") - 1
        want = [np.unique(nbr[src == r]) - start[r] for r in range(comm.size)]
        answers = comm.alltoall([owner[a] for a in comm.alltoall(want)])
        other = np.empty(nbr.size, dtype=np.int32)
        for r in range(comm.size):
            k = src == r
            other[k] = answers[r][np.searchsorted(want[r], nbr[k] - start[r])]
        return _with_ghosts(owner, rows, other, nparts)
    return partition


def mesh_from_local_arrays(comm, x, cells, cell_tag, facets, facet_values, gdim=2, owners=None):
    """A triangle mesh whose parts every rank holds -> (mesh, cell_tags, facet_tags): ``x``
    (n, >= gdim) this rank's block of nodes (the global index of row i is i plus the rows of the
    ranks before), ``cells`` (m, 3) global node indices of this rank's cells, ``facets`` (k, 2)
    global node pairs tagged ``facet_values`` (k,), on any rank.  ``owners`` (m,): the rank each
    cell goes to (:func:`_owners_partition`); None on every rank: no cell moves
    (:func:`_keep_partition`).  (0.9: ``create_mesh`` takes the partitioner and the element.)"""
    x = np.asarray(x, dtype=float)
    x = np.ascontiguousarray(x.reshape(-1, x.shape[-1] if x.size else gdim)[:, :gdim])
    moved = comm.allreduce(owners is not None, op=MPI.LOR)
    if moved and owners is None:
        raise ValueError("mesh_from_local_arrays: owners given on some ranks only; give them on every rank")
    return _mesh_and_tags(comm, np.asarray(cells, dtype=np.int64).reshape(-1, 3), x, cell_tag,
                          np.asarray(facets, np.int64).reshape(-1, 2), np.asarray(facet_values, np.int32),
                          _owners_partition(owners) if moved else _keep_partition, gdim)


def mesh_inputs(mesh, facet_tags):
    """This rank's part of a triangle mesh as the inputs of :func:`mesh_from_local_arrays`, in
    the geometry's global node numbering: (x (n, 2) the owned nodes, cells (c, 3) and their
    coordinates (c, 3, 2) for the owned cells, facets (k, 2) and values (k,) for the owned
    tagged facets).  The mesh made again from them has the same
    cells, nodes and tags on the same ranks (0.9: ``geometry.dofmap`` is a 2D array,
    ``geometry.index_map()`` unchanged)."""
    geo = mesh.geometry
    imap = geo.index_map()
    g_of = np.asarray(imap.local_to_global(np.arange(imap.size_local + imap.num_ghosts, dtype=np.int32)), np.int64)
    tdim = mesh.topology.dim
    nc = mesh.topology.index_map(tdim).size_local
    dof = geo.dofmap.array.reshape(-1, 3)
    x = geo.x[:imap.size_local, :2].copy()
    # vertex -> geometry node (a P1 cell's i-th vertex is its i-th geometry node)
    mesh.topology.create_connectivity(tdim, 0)
    c2v = mesh.topology.connectivity(tdim, 0).array.reshape(-1, 3)
    vmap = mesh.topology.index_map(0)
    v2g = np.empty(vmap.size_local + vmap.num_ghosts, np.int64)
    v2g[c2v.reshape(-1)] = dof[:c2v.shape[0]].reshape(-1)
    mesh.topology.create_connectivity(tdim - 1, 0)
    f2v = mesh.topology.connectivity(tdim - 1, 0).array.reshape(-1, 2)
    idx = np.asarray(facet_tags.indices)
    own = idx < mesh.topology.index_map(tdim - 1).size_local
    fg = v2g[f2v[idx[own]]]
    values = np.asarray(facet_tags.values)[own].astype(np.int32)
    return x, g_of[dof[:nc]], geo.x[dof[:nc], :2].copy(), g_of[fg], values


def gmsh_compiled_size_callback(gmsh, address, data):
    """Set Gmsh's mesh size callback to the compiled C function at ``address`` with the data
    pointer ``data`` (a C-contiguous float64 array, kept alive by the caller until
    ``gmsh.model.mesh.removeSizeCallback()``).  Gmsh 4.8's prototype (Debian 12):
    ``double f(int dim, int tag, double x, double y, double z, void *data)``.  Returns False
    (nothing set) for another Gmsh, whose prototype differs (4.11+ passes ``double lc`` before
    ``data``): the caller then sets a Python callback (the same sizes, slower).  Port: compile
    the callback with the new argument and accept that version here."""
    import ctypes
    if tuple(int(v) for v in gmsh.__version__.split(".")[:2]) != (4, 8):
        return False
    ierr = ctypes.c_int()
    gmsh.lib.gmshModelMeshSetSizeCallback(ctypes.c_void_p(address), data.ctypes.data_as(ctypes.c_void_p),
                                          ctypes.byref(ierr))
    if ierr.value != 0:
        raise RuntimeError(f"Gmsh refused the size callback (error {ierr.value})")
    return True


def meshtags(mesh, dim, entities, values):
    """Sorted MeshTags (0.9: ``dolfinx.mesh.meshtags`` unchanged)."""
    entities = np.asarray(entities, dtype=np.int32)
    values = np.asarray(values, dtype=np.int32)
    order = np.argsort(entities)
    return dolfinx.mesh.meshtags(mesh, dim, entities[order], values[order])


def locate_boundary_facets(mesh, marker):
    """Exterior facets whose midpoint satisfies ``marker(x) -> bool array``."""
    tdim = mesh.topology.dim
    return dolfinx.mesh.locate_entities_boundary(mesh, tdim - 1, marker)


def num_cells_local(mesh):
    return mesh.topology.index_map(mesh.topology.dim).size_local


def num_cells_global(mesh):
    return mesh.topology.index_map(mesh.topology.dim).size_global


def num_cells_with_ghosts(mesh):
    im = mesh.topology.index_map(mesh.topology.dim)
    return im.size_local + im.num_ghosts


def cell_geometry_nodes(mesh):
    """(num_cells incl. ghosts, 3) geometry node indices of each triangle, in the cell's
    reference order (0.9: ``mesh.geometry.dofmap`` is a 2D array)."""
    return mesh.geometry.dofmap.array.reshape(-1, 3)


def cell_vertex_coords(mesh):
    """(num_cells incl. ghosts, 3, 2) coordinates of each triangle's geometry nodes,
    in the cell's reference order."""
    return mesh.geometry.x[cell_geometry_nodes(mesh), :2]


def connectivity(mesh, d0, d1):
    """(offsets, array) of the topology connectivity d0 -> d1 (0.9: ``.offsets``/``.array``)."""
    mesh.topology.create_connectivity(d0, d1)
    c = mesh.topology.connectivity(d0, d1)
    return c.offsets, c.array


def exterior_facet_indices(mesh):
    tdim = mesh.topology.dim
    mesh.topology.create_connectivity(tdim - 1, tdim)
    return dolfinx.mesh.exterior_facet_indices(mesh.topology)


def num_facets_with_ghosts(mesh):
    tdim = mesh.topology.dim
    mesh.topology.create_entities(tdim - 1)
    im = mesh.topology.index_map(tdim - 1)
    return im.size_local + im.num_ghosts


def facet_owned_mask(mesh):
    tdim = mesh.topology.dim
    mesh.topology.create_entities(tdim - 1)
    im = mesh.topology.index_map(tdim - 1)
    mask = np.zeros(im.size_local + im.num_ghosts, dtype=bool)
    mask[: im.size_local] = True
    return mask


# --- spaces and functions -------------------------------------------------------
#: the compiled elements of :func:`dg_space`, by UFL element: (ufcx element, ufcx dofmap, their
#: module's cffi FFI, the C++ element); an element does not depend on the mesh, so a new mesh (a remesh)
#: only numbers its dofs
_COMPILED_ELEMENTS = {}


def dg_space(mesh, degree, dim=None):
    """Discontinuous Lagrange space; ``dim`` components in one blocked dofmap
    (0.9: ``functionspace(mesh, ("DG", degree, (dim,)))``).  The element is compiled (or found
    in FFCx's cache: 1.4 ms of the 1.8 ms of a P2 x 5 space on 3200 cells) once per process; a space on a new mesh then builds only its
    dofmap, as ``dolfinx.fem.FunctionSpace`` does after its JIT call (0.9: the same
    ``FunctionSpace(mesh, element, cppV)`` path)."""
    if dim is None:
        el = ufl.FiniteElement("DG", mesh.ufl_cell(), degree)
    else:
        el = ufl.VectorElement("DG", mesh.ufl_cell(), degree, dim=dim)
    hit = _COMPILED_ELEMENTS.get(el)
    if hit is None:
        (ufcx_element, ufcx_dofmap), module, _ = dolfinx.jit.ffcx_jit(mesh.comm, el)
        ffi = module.ffi
        cpp_element = dolfinx.cpp.fem.FiniteElement(ffi.cast("uintptr_t", ffi.addressof(ufcx_element)))
        hit = _COMPILED_ELEMENTS[el] = (ufcx_element, ufcx_dofmap, ffi, cpp_element)
    ufcx_element, ufcx_dofmap, ffi, cpp_element = hit
    cpp_dofmap = dolfinx.cpp.fem.create_dofmap(mesh.comm, ffi.cast("uintptr_t", ffi.addressof(ufcx_dofmap)),
                                                mesh.topology, cpp_element)
    try:
        cppV = dolfinx.cpp.fem.FunctionSpace(mesh, cpp_element, cpp_dofmap)
    except TypeError:
        cppV = dolfinx.cpp.fem.FunctionSpace(mesh._mesh, cpp_element, cpp_dofmap)
    V = dolfinx.fem.FunctionSpace(mesh, el, cppV)
    V._ufcx_element, V._ufcx_dofmap = ufcx_element, ufcx_dofmap
    return V


def cg_vector_space(mesh, degree):
    """Continuous Lagrange P_degree vector space (the CG baseline; 0.9:
    ``functionspace(mesh, ("Lagrange", degree, (2,)))``)."""
    return dolfinx.fem.VectorFunctionSpace(mesh, ("Lagrange", degree))


def boundary_dofs(V, facets):
    """Local block indices of V's dofs on the given facets."""
    return dolfinx.fem.locate_dofs_topological(V, V.mesh.topology.dim - 1, facets)


def cell_dofs(V):
    """(num_cells incl. ghosts, ndofs_per_cell) block indices of V's dofmap."""
    return V.dofmap.list.array.reshape(-1, V.dofmap.dof_layout.num_dofs)


def dof_counts(V):
    """(owned blocks, ghost blocks, block size, global blocks)."""
    im = V.dofmap.index_map
    return im.size_local, im.num_ghosts, V.dofmap.index_map_bs, im.size_global


def dof_coordinates(V):
    return V.tabulate_dof_coordinates()


def function(V, name=None):
    return dolfinx.fem.Function(V, name=name)


def function_array(u):
    """Local array (owned + ghosts) of a Function (0.9: ``u.x.array``)."""
    return u.x.array


def scatter_forward(u):
    u.x.scatter_forward()


def constant(mesh, value):
    return dolfinx.fem.Constant(mesh, np.asarray(value, dtype=dolfinx.default_scalar_type
                                                 if hasattr(dolfinx, "default_scalar_type") else np.float64))


# --- forms and assembly -----------------------------------------------------------
def form(expr):
    return dolfinx.fem.form(expr)


def assemble_matrix(a):
    A = dolfinx.fem.petsc.assemble_matrix(a)
    A.assemble()
    return A


def assemble_vector(L):
    """Assembled, ghost-accumulated PETSc vector (owned part valid)."""
    from petsc4py import PETSc
    b = dolfinx.fem.petsc.assemble_vector(L)
    b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
    return b


def assemble_scalar(M, comm):
    return comm.allreduce(dolfinx.fem.assemble_scalar(M), op=MPI.SUM)


def destroy(*objects):
    """Free PETSc objects (vectors, matrices) now; None and freed ones are skipped.  Collective
    over each object's communicator.  petsc4py 3.18 does not free an object that Python drops:
    its memory stays until PetscFinalize (petsc issue 1309; DOLFINx's ``create_vector`` asks the
    caller to call ``destroy()``).  A remesh that dropped its old solver leaked every vector of
    it (docs/benchmarks.md, "A remesh freed none of the old solver's vectors").  Unchanged in
    newer petsc4py, where ``destroy()`` is still the documented way.  Returns the number freed."""
    live = [obj for obj in objects if obj is not None and obj.handle]
    for obj in live:
        obj.destroy()
    return len(live)


def create_vector(V):
    """Ghosted PETSc vector with V's layout (0.9: ``dolfinx.fem.petsc.create_vector``)."""
    return dolfinx.la.create_petsc_vector(V.dofmap.index_map, V.dofmap.index_map_bs)


def measure(kind, mesh, subdomain_data=None, **kw):
    return ufl.Measure(kind, domain=mesh, subdomain_data=subdomain_data, **kw)


def function_vector(u):
    """The PETSc vector of a Function (0.9: ``u.x.petsc_vec``)."""
    return u.vector


def function_vector_made(u):
    """The PETSc vector that :func:`function_vector` made of ``u``'s array, or None if it made
    none (0.5 keeps it in ``_petsc_x``; 0.9: ``u.x._petsc_x``)."""
    return getattr(u, "_petsc_x", None)


def index_offset(V):
    """Global index of this rank's first owned block (0.9: ``index_map.local_range[0]`` still)."""
    return V.dofmap.index_map.local_range[0]


def function_array_of_vec(vec):
    """Copy of the local (owned + ghost) values of a ghosted PETSc vector, ghosts updated."""
    from petsc4py import PETSc
    vec.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
    with vec.localForm() as loc:
        return loc.array_r.copy()


def vertex_to_geometry(mesh):
    """Map topology vertex index -> geometry node index (affine meshes; 0.9:
    ``mesh.geometry.dofmap`` is a 2D array)."""
    tdim = mesh.topology.dim
    c_off, c_arr = connectivity(mesh, tdim, 0)
    xdofs = mesh.geometry.dofmap.array.reshape(-1, 3)
    im = mesh.topology.index_map(0)
    v2g = np.zeros(im.size_local + im.num_ghosts, dtype=np.int64)
    v2g[c_arr.reshape(-1, 3)] = xdofs[: c_arr.size // 3]
    return v2g


def locate_facets(mesh, marker):
    """All local facets (interior or not) whose vertices satisfy ``marker``."""
    return dolfinx.mesh.locate_entities(mesh, mesh.topology.dim - 1, marker)


def vertex_global_indices(mesh, local_vertices):
    """Global vertex numbers of local vertex indices (any shape)."""
    lv = np.asarray(local_vertices, dtype=np.int32)
    if lv.size == 0:
        return lv.astype(np.int64)
    return mesh.topology.index_map(0).local_to_global(lv.reshape(-1)).reshape(lv.shape).astype(np.int64)


def mesh_arrays(mesh):
    """(x (n, 2), cells (num_cells, 3)) of an affine triangle mesh on one process: geometry
    node coordinates and each cell's node indices (0.9: ``mesh.geometry.dofmap`` is 2D)."""
    if mesh.comm.size > 1:
        raise ValueError("mesh_arrays needs a mesh on one process (MPI.COMM_SELF)")
    return mesh.geometry.x[:, :2].copy(), mesh.geometry.dofmap.array.reshape(-1, 3).copy()


def create_mesh(comm, cells, x, rank=0):
    """Affine triangle mesh from arrays held on ``rank`` (others pass empty arrays)
    (0.9: ``dolfinx.mesh.create_mesh(comm, cells, x, ufl.Mesh(element("Lagrange", "triangle",
    1, shape=(2,))))``)."""
    domain = ufl.Mesh(ufl.VectorElement("Lagrange", ufl.triangle, 1))
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    x = np.asarray(x, dtype=float).reshape(-1, 2)
    if comm.rank != rank:
        cells, x = np.empty((0, 3), np.int64), np.empty((0, 2))
    return dolfinx.mesh.create_mesh(comm, cells, x, domain, ghost_mode=GHOST_MODE)


def eval_function(u, points, cells):
    """Values of Function ``u`` at ``points`` (m, 2) inside the given local ``cells`` (m,)."""
    pts = np.zeros((len(points), 3))
    pts[:, :2] = points
    return u.eval(pts, np.asarray(cells, dtype=np.int32))


def tags_present(comm, tags) -> set:
    """The tag values present on any rank: ``tags`` is a MeshTags (or None) or an array of
    values (collective)."""
    values = np.zeros(0) if tags is None else (tags.values if hasattr(tags, "values") else np.asarray(tags))
    return set().union(*comm.allgather(set(np.unique(values).tolist())))


def require_tags(comm, tags, wanted, what, where, fix):
    """Raise ValueError on every rank if any of ``wanted`` is missing from ``tags``
    (:func:`tags_present`), naming them, what is present and the fix."""
    present = tags_present(comm, tags)
    missing = sorted(set(wanted) - present)
    if missing:
        raise ValueError(f"{what} tag(s) {missing} are not in {where} {sorted(present)}; {fix}")


def cells_containing(mesh, points, cells=None):
    """(point index, local cell) pairs of every cell (owned or ghost) that contains one of the
    ``points`` (m, 2), by DOLFINx's bounding-box tree (0.9: ``bb_tree`` and the same
    ``compute_*`` calls).  The tree of all cells is built once per mesh; with ``cells`` (local
    indices, a superset of the cells wanted) a tree of those cells only is built for this
    call."""
    import dolfinx.geometry
    if cells is not None:
        if not len(cells):
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim, np.asarray(cells, dtype=np.int32))
    else:
        tree = getattr(mesh, "_hydrofrac_bb_tree", None)
        if tree is None:
            tree = dolfinx.geometry.BoundingBoxTree(mesh, mesh.topology.dim)
            mesh._hydrofrac_bb_tree = tree
    X = np.zeros((len(points), 3))
    X[:, :2] = points
    hits = dolfinx.geometry.compute_colliding_cells(mesh, dolfinx.geometry.compute_collisions(tree, X), X)
    offsets = np.asarray(hits.offsets)
    return np.repeat(np.arange(len(points)), np.diff(offsets)), np.asarray(hits.array, dtype=np.int64)


def facet_cells(mesh, facets):
    """The first cell of each facet (the only one for an exterior facet)."""
    tdim = mesh.topology.dim
    off, arr = connectivity(mesh, tdim - 1, tdim)
    return arr[off[np.asarray(facets)]]


def facet_nodes(mesh, facets):
    """(m, 2) geometry node indices of the two end vertices of each facet (local)."""
    tdim = mesh.topology.dim
    off, arr = connectivity(mesh, tdim - 1, 0)
    f = np.asarray(facets)
    return vertex_to_geometry(mesh)[np.stack([arr[off[f]], arr[off[f] + 1]], axis=1)]
