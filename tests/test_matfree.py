"""The matrix-free bulk operator (hydrofrac.matfree) against the operator assembled from
the UFL forms of forms/elastodynamics.py: the same right-hand side to round-off.

One mesh exercises everything the operator touches: two materials (impedance jumps on
interior facets), perturbed (non-uniform) affine cells, excluded crack facets, and every
boundary condition kind (assembled on the boundary cells in both modes).  Random states
(not smooth fields) so that every basis function and every facet trace counts.  Run
serially and, with the ``mpi`` marker, on 2 ranks (facets on the partition boundary).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from mpi4py import MPI

import exact
from exact import BOTTOM, LEFT, RIGHT, TOP
from hydrofrac import CONFINEMENT, ROCK, Material, compat
from hydrofrac.boundary import Absorbing, OuterState, PiecewiseLinear, Slider, Symmetry, Traction, Velocity
from hydrofrac._jit import njit
from hydrofrac.solver import Solver

SIGMA0 = ((-CONFINEMENT, 0.0), (0.0, -CONFINEMENT))
MEDIUM2 = Material(E=40e9, nu=0.25, rho=2700.0, name="medium 2")
# round-off: every output value sums O(nb^2) products of random values of both signs,
# with derivative factors up to p^2/h relative to the values; 1e-11 of the largest output
# value is ~5e4 machine epsilons.  Measured: 5e-16 (p = 1) to 4e-12 (p = 4).
RTOL = 1e-11


def mesh_data(comm, N=10):
    """One mesh for both operators (in parallel, two meshes may be partitioned differently)."""
    mesh, ft = exact.unit_square(N, comm=comm)
    exact.perturb_interior(mesh, 0.2, 1.0 / N)
    centroid = compat.cell_vertex_coords(mesh).mean(axis=1)
    ct = compat.meshtags(mesh, mesh.topology.dim, np.arange(centroid.shape[0]),
                         np.where(centroid[:, 0] < 0.5, 1, 2))
    crack = compat.locate_facets(mesh, lambda x: np.isclose(x[0], 0.3) & (x[1] > 0.25) & (x[1] < 0.75))
    return mesh, ft, ct, crack


def outer_state(x, t):
    """A smooth outer state (5, m) that changes in time."""
    return np.stack([np.sin(3 * x[0] + t), np.cos(2 * x[1]), ROCK.Zd * x[0] * x[1], -ROCK.Zd * (x[0] + t),
                     ROCK.Zs * np.sin(x[1] - x[0])])


ZD, ZS = float(ROCK.Zd), float(ROCK.Zs)


@njit
def outer_state_pt(x, y, t):
    """:func:`outer_state` at one point, compiled."""
    return math.sin(3 * x + t), math.cos(2 * y), ZD * x * y, -ZD * (x + t), ZS * math.sin(y - x)


def problem(data, p, operator, kinds="loads", point=None, scheme="rk4"):
    """``kinds``: "loads" (traction with a pressure history, absorbing, symmetry, constant
    velocity) or "outer" (an outer state, a slider, a velocity history, and a traction-free
    side without a condition)."""
    mesh, ft, ct, crack = data
    history = PiecewiseLinear((0.0, 1.0), (1e6, 2e6))
    if kinds == "loads":
        bcs = [Traction(LEFT, stress=SIGMA0, pressure=history), Absorbing(RIGHT, stress=SIGMA0),
               Symmetry(BOTTOM), Velocity(TOP, value=(0.1, -0.2))]
    else:
        bcs = [OuterState(LEFT, outer_state, point), Slider(RIGHT),
               Velocity(TOP, value=(0.3, 0.1), history=PiecewiseLinear((0.0, 1.0), (0.5, 2.0)))]
    return Solver(mesh, p, {1: ROCK, 2: MEDIUM2}, cell_tags=ct, facet_tags=ft, bcs=bcs, sigma0=SIGMA0,
                  crack_facets=crack, operator=operator, scheme=scheme)


def random_rhs(solver, seed=7):
    """rhs of a random state given by a hash of the DG node and cell coordinates, scaled like
    a wave state (|v| ~ 1 m/s, |sigma| ~ Z |v|)."""
    X = compat.dof_coordinates(solver.V)[:, :2]
    h = np.floor(X[:, 0] * 997.0) * 1009.0 + np.floor(X[:, 1] * 991.0)  # node key
    dofs = compat.cell_dofs(solver.V)
    cell_of = np.zeros(X.shape[0], dtype=np.int64)
    cell_of[dofs.reshape(-1)] = np.repeat(np.arange(dofs.shape[0]), dofs.shape[1])
    cent = solver.geometry.vertices.mean(axis=1)[cell_of]
    key = h + 7.0 * np.floor(cent[:, 0] * 9973.0) + 3.0 * np.floor(cent[:, 1] * 9967.0)
    vals = np.stack([np.sin(seed * (k + 1) * (key % 104729.0)) for k in range(5)], axis=1)
    vals[:, 2:] *= ROCK.Zd
    with solver.x.localForm() as xl:
        xl.array[:] = vals.reshape(-1)
    out = solver.x_like()
    solver.rhs(solver.x, 0.5, out)
    return compat.function_array_of_vec(out).reshape(-1, 5), X


def compare(comm, p, kinds="loads", point=None):
    data = mesh_data(comm)
    a, X = random_rhs(problem(data, p, "assembled", kinds))
    b, _ = random_rhs(problem(data, p, "matfree", kinds, point))
    err = comm.allreduce(float(np.abs(a - b).max()) if a.size else 0.0, op=MPI.MAX)
    scale = comm.allreduce(float(np.abs(a).max()) if a.size else 0.0, op=MPI.MAX)
    return err / scale, scale


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_matfree_equals_assembled(p):
    rel, scale = compare(MPI.COMM_WORLD, p)
    assert scale > 0
    assert rel < RTOL, f"p = {p}: matrix-free vs assembled relative difference {rel:.3e}"


@pytest.mark.parametrize("p", [1, 3])
def test_matfree_boundary_kinds_equal_assembled(p):
    """The boundary kernel's other kinds: an outer state, a slider, a velocity history and a
    traction-free side without a condition."""
    rel, scale = compare(MPI.COMM_WORLD, p, "outer")
    assert scale > 0
    assert rel < RTOL, f"p = {p}: matrix-free vs assembled relative difference {rel:.3e}"


def test_compiled_outer_state_equals_python():
    """An outer state given as a compiled point function gives the rhs of the Python one; a
    point function of another state is refused before the run."""
    data = mesh_data(MPI.COMM_WORLD)
    a, _ = random_rhs(problem(data, 2, "matfree", "outer"))
    b, _ = random_rhs(problem(data, 2, "matfree", "outer", point=outer_state_pt))
    np.testing.assert_allclose(b, a, rtol=0, atol=1e-13 * np.abs(a).max())

    @njit
    def other(x, y, t):
        return outer_state_pt(x, y, t + 0.1)

    with pytest.raises(ValueError, match="differ at the boundary nodes"):
        problem(data, 2, "matfree", "outer", point=other)
    with pytest.raises(ValueError, match="numba.njit point function"):
        OuterState(LEFT, outer_state, point=lambda x, y, t: (0.0,) * 5)


@pytest.mark.mpi
@pytest.mark.parametrize("p,kinds", [(1, "loads"), (3, "loads"), (2, "outer")])
def test_matfree_equals_assembled_parallel(p, kinds):
    """(The outer state compiled: its check is collective, with ranks that have none of its facets.)"""
    comm = MPI.COMM_WORLD
    rel, scale = compare(comm, p, kinds, outer_state_pt if kinds == "outer" else None)
    assert rel < RTOL, f"p = {p}, {comm.size} ranks: relative difference {rel:.3e}"


@pytest.mark.parametrize("p,kinds", [(1, "loads"), (3, "loads"), (2, "outer")])
def test_matfree_energy_terms_equal_assembled(p, kinds):
    """Kinetic and strain energy (cell kernel vs the assembled mass matrix), the upwind
    dissipation rate on interior and boundary facets (facet kernels vs the assembled quadratic
    forms) and the boundary power in and out (boundary kernel vs the assembled power forms,
    with the histories and the outer state at t = 0.5) agree.  The energies and the
    dissipation are sums of positive terms, so round-off is relative to the value; the powers
    are signed sums, compared relative to the sum of their terms' sizes, bounded by the
    dissipation's scale."""
    comm = MPI.COMM_WORLD
    data = mesh_data(comm)
    vals = []
    for operator in ("assembled", "matfree"):
        solver = problem(data, p, operator, kinds)
        random_rhs(solver)  # sets the random state
        solver.t = 0.5
        kin, strain = solver.energies()
        p_in, p_out, diss = solver.account.rates()
        vals.append(np.array([kin, strain, diss, p_in, p_out]))
    assert np.all(vals[0][:3] > 0) and vals[0][3] != 0 and vals[0][4] != 0
    np.testing.assert_allclose(vals[1][:3], vals[0][:3], rtol=1e-12)
    np.testing.assert_allclose(vals[1][3:], vals[0][3:], rtol=1e-10)


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_c_volume_kernel_equals_numba(p, monkeypatch):
    """The C volume kernel (hydrofrac/volume.c, blocks of cells in the vector lanes) against
    the numba one: the same arithmetic per cell, so the same rhs up to the FMA contraction and
    reassociation the two compilers choose (measured 3e-16 to 6e-16 relative); 1e-13 is ~500
    machine epsilons.  The mesh's cell count is not a multiple of the block size, so the short
    last block is covered."""
    data = mesh_data(MPI.COMM_WORLD, N=9)
    out = {}
    for kernels in ("numba", "c"):
        monkeypatch.setenv("HYDROFRAC_KERNELS", kernels)
        solver = problem(data, p, "matfree")
        assert solver.matfree.kernels == kernels
        out[kernels], _ = random_rhs(solver)
    assert solver.matfree.nowned % 4 != 0
    scale = np.abs(out["numba"]).max()
    assert scale > 0
    np.testing.assert_allclose(out["c"], out["numba"], rtol=0, atol=1e-13 * scale)


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_c_energy_kernel_equals_numba(p, monkeypatch):
    """The energy budget's cell energies in C (blocks of cells in the vector lanes) against
    numba, on a random state less the initial one: the same sums of positive terms to
    round-off (measured 1e-16 to 2e-15 relative), on a mesh whose cell count is not a
    multiple of the block size."""
    data = mesh_data(MPI.COMM_WORLD, N=9)
    out = {}
    for kernels in ("numba", "c"):
        monkeypatch.setenv("HYDROFRAC_KERNELS", kernels)
        solver = problem(data, p, "matfree")
        assert (solver.matfree._cenergy is not None) == (kernels == "c")
        random_rhs(solver)
        out[kernels] = np.array(solver.energies())
    assert solver.matfree.nowned % 4 != 0 and np.all(out["numba"] > 0)
    np.testing.assert_allclose(out["c"], out["numba"], rtol=1e-13)


@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_c_dissipation_kernel_equals_numba(p, monkeypatch):
    """The energy budget's upwind dissipation on the interior facets in C (blocks of facets in
    the vector lanes, coefficients per impedance pair) against numba, on a random state of the
    two-material mesh: the same sum of positive terms to round-off (measured 1e-16 to 1e-15
    relative), with a facet count that is not a multiple of the block size."""
    data = mesh_data(MPI.COMM_WORLD, N=9)
    out = {}
    for kernels in ("numba", "c"):
        monkeypatch.setenv("HYDROFRAC_KERNELS", kernels)
        solver = problem(data, p, "matfree")
        mf = solver.matfree
        assert (mf._cdiss is not None) == (kernels == "c")
        random_rhs(solver)
        solver.update_ghosts(solver.x)
        with solver.read_local(solver.x) as X:
            out[kernels] = solver.comm.allreduce(mf.dissipation_rate(X), op=MPI.SUM)
    assert (mf.fcells.shape[0] % 4 != 0 or solver.comm.size > 1) and out["numba"] > 0
    assert out["c"] == pytest.approx(out["numba"], rel=1e-13, abs=0)


@pytest.mark.parametrize("p", [1, 2, 3])
def test_c_ader_kernel_equals_numba(p, monkeypatch):
    """ADER's corrector and predictor in C against numba: two steps from a random state (the
    first runs the predictor, the second reuses the corrector's), the same fields to round-off."""
    data = mesh_data(MPI.COMM_WORLD, N=9)
    out = {}
    for kernels in ("numba", "c"):
        monkeypatch.setenv("HYDROFRAC_KERNELS", kernels)
        solver = problem(data, p, "matfree", scheme="ader")
        random_rhs(solver)
        for _ in range(2):
            solver.step()
        assert (solver.matfree._cader is not None) == (kernels == "c")
        out[kernels] = solver.x.array_r.copy()
    scale = np.abs(out["numba"]).max()
    np.testing.assert_allclose(out["c"], out["numba"], rtol=0, atol=1e-13 * scale)

@pytest.mark.parametrize("p", [1, 2, 3, 4])
def test_taylor_chain_gives_the_nodal_derivatives_in_the_degrees_they_have(p):
    """The C predictor's chain (``matfree.taylor_chain``): each link's derivatives of a random
    P_p field, held on the (p - m)-lattice and interpolated at the nodes, equal the nodal
    derivative matrices D_r = Minv_ref S_r applied m times (any mix of directions), to
    round-off; a chain that holds D^m x on a lattice a degree too low fails."""
    solver = Solver(exact.unit_square(2, comm=MPI.COMM_SELF)[0], p, ROCK)
    mf = solver.matfree
    D = [mf.Minv_ref @ S for S in (mf.S0, mf.S1)]
    chain, nb = mf.chain, mf.S0.shape[0]
    rng = np.random.default_rng(p)
    dim = [(k + 1) * (k + 2) // 2 for k in range(p + 1)]
    for dirs in ([0] * p, [1] * p, [m % 2 for m in range(p)]):
        x = rng.standard_normal(nb)
        nodal, held, at = x.copy(), x.copy(), 0
        for m, r in enumerate(dirs, start=1):
            n_in, n_out = (nb if m == 1 else dim[p - m + 1]), dim[p - m]
            A = chain[at + r * n_out * n_in: at + (r + 1) * n_out * n_in].reshape(n_out, n_in)
            V = chain[at + 2 * n_out * n_in: at + 2 * n_out * n_in + nb * n_out].reshape(nb, n_out)
            at += 2 * n_out * n_in + nb * n_out
            nodal, held = D[r] @ nodal, A @ held
            np.testing.assert_allclose(V @ held, nodal, rtol=0, atol=1e-10 * np.abs(x).max() * 4.0 ** m)
        assert at == chain.size



def test_kernels_choice_is_checked(monkeypatch, tmp_path):
    """A misspelt HYDROFRAC_KERNELS and a compiler that fails are errors naming the fix, not a
    silent fall-back to the numba kernels."""
    from hydrofrac import native
    monkeypatch.setenv("HYDROFRAC_KERNELS", "fortran")
    with pytest.raises(ValueError, match="HYDROFRAC_KERNELS must be one of c, numba"):
        native.backend()
    monkeypatch.setenv("HYDROFRAC_KERNELS", "c")
    monkeypatch.setenv("CC", "false")
    monkeypatch.setenv("HYDROFRAC_CACHE", str(tmp_path))
    native._identity.cache_clear()
    native._library.cache_clear()
    try:
        with pytest.raises(native.NativeError, match="HYDROFRAC_KERNELS=numba"):
            problem(mesh_data(MPI.COMM_WORLD, N=4), 2, "matfree")
    finally:
        native._identity.cache_clear()
        native._library.cache_clear()
    assert not list(tmp_path.iterdir())  # no half-written library left behind


def test_facet_codes_are_the_reference_edges_the_facets_map_to():
    """Each facet's reference edge in each of its cells (code 3 i + j: from reference vertex i
    to j) is found from the cell's geometry nodes; it is the edge the facet's end points map to
    through the cell's affine map, for every interior and boundary facet of a mesh that is not
    structured (a fracture mesh: its cells come in every orientation)."""
    from hydrofrac.meshes.fractures import Domain, Fracture, fracture_mesh
    dom = Domain(half_width=1.0, half_height=1.0, h_crack=0.1, h_far=0.3, grading=0.5, wellbore_radius=0.0)
    fm = fracture_mesh(MPI.COMM_WORLD, dom, fractures=[Fracture(center=(0.1, 0.0), angle=30.0, length=0.8)])
    s = Solver(fm.mesh, 2, ROCK)
    mf, g = s.matfree, s.geometry
    vert = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])

    def mapped(cells, codes):
        # reference vertices i and j of each cell, mapped to physical space
        i, j = codes // 3, codes % 3
        xa = g.x0[cells] + np.einsum("cij,cj->ci", g.J[cells], vert[i])
        xb = g.x0[cells] + np.einsum("cij,cj->ci", g.J[cells], vert[j])
        return xa, xb

    checked = 0
    for side in range(2):
        xa, xb = mapped(mf.fcells[:, side], mf.fcodes[:, side])
        t = np.stack([-mf.normal[:, 1], mf.normal[:, 0]], axis=1)  # va -> vb: n is its tangent turned clockwise
        np.testing.assert_allclose(xb - xa, t * mf.length[:, None], atol=1e-12)
        checked += len(xa)
    xa, xb = mapped(mf.bcells, mf.bcodes)
    assert np.allclose(np.linalg.norm(xb - xa, axis=1), mf.blength, atol=1e-12)
    assert checked > 0 and len(xa) > 0


def test_reference_data_is_made_once_per_element():
    """A solver on a new mesh (a remesh) reuses the element's reference data (derivative and
    mass matrices, edge tables) instead of computing them again (docs/benchmarks.md,
    "Reference data once per element"); they equal freshly computed ones, bit for bit."""
    from hydrofrac import matfree
    comm = MPI.COMM_WORLD
    a = Solver(exact.unit_square(4, comm=comm)[0], 2, ROCK)
    b = Solver(exact.unit_square(6, comm=comm)[0], 2, ROCK)
    assert b.matfree.S0 is a.matfree.S0 and b.matfree.tables is a.matfree.tables and b.Mref_inv is a.Mref_inv
    fresh = matfree._REFERENCE.pop((a.ref.degree, a.ref.nodes.shape, a.ref.nodes.tobytes()))
    again = matfree.reference_data(b.ref)
    assert again is not fresh
    assert all(np.array_equal(x, y) for x, y in zip(again, fresh))
    assert Solver(exact.unit_square(4, comm=comm)[0], 3, ROCK).matfree.S0.shape == (10, 10)


def test_matrix_free_set_up_builds_only_what_it_uses():
    """A matrix-free solver (every remesh makes one) builds no DG0 material Functions, no x0
    vector and no energy pass at its uniform initial state (docs/benchmarks.md, "The solver
    builds only what the run uses"); a form that asks for rho, lambda or mu gets them, per
    cell, and the energies subtract the uniform state as x - x0 did."""
    comm = MPI.COMM_WORLD
    s = Solver(exact.unit_square(4, comm=comm)[0], 2, ROCK, sigma0=((-2e6, 3e5), (3e5, -1e6)))
    assert s._coefficients is None and not hasattr(s, "x0")
    assert len(s._work) == s.num_stages + 1
    assert s.energy.kinetic == 0.0 and s.energy.strain == 0.0
    rho = compat.function_array(s.rho)
    q0 = compat.cell_dofs(s.rho.function_space)[:, 0]
    assert np.array_equal(rho[q0], s.rho_cell) and np.array_equal(compat.function_array(s.mu)[q0], s.mu_cell)
    # a perturbation d of the initial state has the energies of d on its own (no initial stress)
    a = Solver(exact.unit_square(4, comm=comm)[0], 2, ROCK)
    for solver in (s, a):
        with solver.x.localForm() as xl:
            xl.array[:] += 1e4 * np.sin(np.arange(xl.array.size))
    assert np.allclose(s.energies(), a.energies(), rtol=1e-9, atol=0)
    assert min(s.energies()) > 0


def _check_taylor_values(p, monkeypatch):
    """ADER's Taylor values on a list of cells (the traces the crack interfaces read inside a
    step), at two times: the C kernel (hydrofrac/volume.c, the predictor on listed cells, ghosts
    included) and the numba path equal each other to round-off, and on the listed owned cells
    both equal sum_m tau^m/m! D^m x built from the operator's own ``local_derivative``; the
    blocks of cells not listed are left as they were.  The list's length is not a multiple of
    the block size and, on 2 ranks, it holds ghost cells."""
    data = mesh_data(MPI.COMM_WORLD, N=9)
    out = {}
    for kernels in ("numba", "c"):
        monkeypatch.setenv("HYDROFRAC_KERNELS", kernels)
        solver = problem(data, p, "matfree", scheme="ader")
        mf = solver.matfree
        random_rhs(solver)
        solver.update_ghosts(solver.x)
        nb, ncells, owned = mf.dofs.shape[1], mf.dofs.shape[0], mf.nowned
        cells = np.arange(1, ncells, 3, dtype=np.int64)
        taus = [0.37 * solver.dt, 1.1 * solver.dt]
        with solver.read_local(solver.x) as X:
            Q = np.full((2, X.size), np.pi)
            mf.taylor_values(X, Q, cells, taus, p)
        assert (mf._ctaylor is not None) == (kernels == "c")
        # the series on the owned cells, term by term
        x = solver.x.array_r.copy()
        ref = [x.copy() for _ in taus]
        term = x.copy()
        for m in range(1, p + 1):
            nxt = np.zeros_like(term)
            mf.local_derivative(term, nxt)
            term = nxt
            for r, tau in zip(ref, taus):
                r += tau ** m / math.factorial(m) * term
        listed = np.zeros(ncells, dtype=bool)
        listed[cells] = True
        blocks = np.repeat(listed, 5 * nb)
        assert np.all(Q[:, ~blocks] == np.pi)
        own = blocks[:5 * nb * owned]
        scale = np.abs(Q[:, blocks]).max()
        for i in range(2):
            np.testing.assert_allclose(Q[i, :5 * nb * owned][own], ref[i][own], rtol=0, atol=1e-12 * scale)
            assert np.abs(Q[i, :5 * nb * owned][own] - x[own]).max() > 1e-6 * scale  # (the terms count)
        out[kernels] = Q[:, blocks]
    assert cells.size % 4 != 0 and (solver.comm.size == 1 or cells.max() >= owned)
    np.testing.assert_allclose(out["c"], out["numba"], rtol=0, atol=1e-13 * np.abs(out["numba"]).max())


@pytest.mark.parametrize("p", [1, 2, 3])
def test_c_taylor_values_equal_the_series_of_the_local_derivative(p, monkeypatch):
    _check_taylor_values(p, monkeypatch)


@pytest.mark.mpi
@pytest.mark.parametrize("p", [2, 3])
def test_c_taylor_values_equal_the_series_of_the_local_derivative_on_2_ranks(p, monkeypatch):
    """As the serial test, with ghost cells in the list (their values come from the halo)."""
    _check_taylor_values(p, monkeypatch)
