"""Shared helpers of the test suite.

Tests run with the project's Python (``make test`` uses ``.venv/bin/python``);
scripts started from tests use the same interpreter (``sys.executable``).
"""
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def repo_root() -> Path:
    """The repository root (scenarios/, tests/, ...)."""
    return ROOT


#: OpenMPI refuses to start as root (CI containers) without these
MPI_ENV = {"OMPI_ALLOW_RUN_AS_ROOT": "1", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM": "1"}


def _run(cmd, timeout=600, cwd=ROOT):
    """Run ``cmd`` (a list); fail the test with its output if it exits non-zero; returns stdout."""
    cmd = [str(c) for c in cmd]
    res = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env={**os.environ, **MPI_ENV})
    if res.returncode != 0:
        pytest.fail(f"{' '.join(cmd)} exited with {res.returncode}\n--- stdout ---\n{res.stdout[-4000:]}"
                    f"\n--- stderr ---\n{res.stderr[-4000:]}")
    return res.stdout


@pytest.fixture(scope="session")
def run_command():
    """``run_command([...], timeout=600)``: run a command in the repository root, fail on a non-zero exit."""
    return _run


@pytest.fixture(scope="session")
def run_python():
    """``run_python([script, args...])``: the same with the interpreter that runs the tests."""
    return lambda args, timeout=600, cwd=ROOT: _run([sys.executable, *args], timeout=timeout, cwd=cwd)


@pytest.fixture(scope="session")
def mpirun():
    """``mpirun(n)``: the command prefix that starts n ranks of the test interpreter."""
    if shutil.which("mpirun") is None:
        pytest.skip("mpirun is not installed (Debian package openmpi-bin, pulled in by python3-dolfinx)")
    return lambda n: ["mpirun", "--oversubscribe", "-n", str(n), sys.executable]


def pytest_exception_interact(node, call, report):
    """Under mpirun, a test that fails on one rank leaves the others waiting in their next
    collective until the suite's timeout: print the failure and abort all ranks at once."""
    from mpi4py import MPI
    comm = MPI.COMM_WORLD
    if comm.size > 1:
        sys.stderr.write(f"\n[rank {comm.rank}] {report.nodeid} failed; aborting all ranks:\n"
                         f"{report.longreprtext}\n")
        sys.stderr.flush()
        comm.Abort(1)
