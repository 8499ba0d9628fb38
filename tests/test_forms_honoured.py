"""An edited bulk form is honoured: the matrix-free kernels implement the forms of
``forms/elastodynamics.py`` by hand, so after an edit the solver must use the operator
assembled from the edited forms (and say so), and the run must follow the edit."""
import numpy as np
import ufl
from mpi4py import MPI

from hydrofrac import ROCK, compat
from hydrofrac.forms import elastodynamics as ef
from hydrofrac.solver import Solver

C_DAMP = 5000.0  # 1/s


def damped_volume(U, W, dx, _volume=ef.volume):
    """The volume term plus a damping -c rho v.w (a user's edit)."""
    v, _ = ef.fields(U)
    w, _ = ef.fields(W)
    return _volume(U, W, dx) - C_DAMP * ROCK.rho * ufl.inner(v, w) * dx


def kinetic_after(steps=40):
    mesh = compat.create_rectangle(MPI.COMM_WORLD, (0.0, 0.0), (1.0, 1.0), 6, 6)
    solver = Solver(mesh, 2, ROCK)
    solver.set_initial_state(lambda x: np.vstack([np.sin(np.pi * x[0]) * np.sin(np.pi * x[1])] + [0 * x[0]] * 4))
    for _ in range(steps):
        solver.step()
    return solver, solver.energies()[0]


def test_edited_volume_form_is_followed(monkeypatch, capsys):
    plain, k_plain = kinetic_after()
    assert plain.operator == "matfree"
    monkeypatch.setattr(ef, "volume", damped_volume)
    edited, k_edited = kinetic_after()
    assert edited.operator == "assembled"
    assert "differ from the ones the matrix-free kernels implement" in capsys.readouterr().out
    # 40 steps of dt: the damping takes exp(-2 c t) of the kinetic energy, give or take the
    # exchange with strain energy; without the edit followed the two runs would be identical
    t = plain.t
    assert k_edited < k_plain * np.exp(-2 * C_DAMP * t) * 1.5
    assert k_edited < 0.9 * k_plain
