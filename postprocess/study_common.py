"""Pieces shared by the study scripts (``study_*.py``): loading a scenario module, the
common command line, and a timed run of a solver."""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

from mpi4py import MPI

SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def scenario(name):
    """The module ``scenarios/<name>.py`` (loaded once; the scenarios are scripts, not a package)."""
    key = f"hydrofrac_scenario_{name}"
    if key not in sys.modules:
        spec = importlib.util.spec_from_file_location(key, SCENARIOS / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        sys.modules[key] = module
        spec.loader.exec_module(module)
    return sys.modules[key]


def study_parser(doc):
    """``--quick`` and ``--out`` (default ``postprocess/results``), described by the module's
    first docstring line."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer and smaller cases (seconds)")
    parser.add_argument("--out", default="postprocess/results")
    return parser


def timed_run(solver, t_end, on_step=None):
    """Step ``solver`` to ``t_end`` with the energy budget and the blow-up check, calling
    ``on_step(solver)`` after each step; returns the wall time (max over ranks) [s]."""
    comm = solver.comm
    comm.barrier()
    t0 = time.perf_counter()
    solver.update_energy()
    while solver.t < t_end * (1 - 1e-12):
        solver.step()
        solver.update_energy()
        solver.check_stability()
        if on_step is not None:
            on_step(solver)
    comm.barrier()
    return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
