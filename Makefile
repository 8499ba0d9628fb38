# hydrofrac: set-up, demo, tests and benchmark.
#
#   make setup   Debian packages (only the missing ones), .venv, editable install
#   make demo    the regularised crack intersection + figures, charts, animation (2 ranks if 2 cores)
#   make test    serial tests, then the MPI tests on 2 ranks
#   make bench   bulk throughput + work-precision benchmark on 1 and 2 ranks, contact stability study
#   make studies the speed-against-accuracy studies (DG vs CG, crack problems, contact, mesh grading)
#
# DOLFINx, PETSc, Gmsh, NumPy, SciPy, numba, matplotlib and ParaView come from
# Debian 12; the venv sees them (--system-site-packages) and adds pyvista (and what it needs).
# constraints.txt pins NumPy to the Debian version so pip never replaces it, and what pyvista pulls in.

SHELL := /bin/bash
.DEFAULT_GOAL := help

# OpenMPI refuses to run as root (CI containers) without these
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1

APT_PACKAGES := python3-dolfinx python3-gmsh python3-meshio python3-scipy python3-pytest python3-mpi4py \
                python3-numba python3-matplotlib python3-venv python3-pip paraview python3-paraview xvfb
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
NPROC := $(shell nproc 2>/dev/null || echo 1)
# --oversubscribe: 2 ranks also run on a 1-core CI machine
MPIRUN := mpirun --oversubscribe
# wall-clock limits [s] of the test passes: a deadlocked MPI test must not eat the CI budget
TEST_TIMEOUT ?= 1800
TEST_TIMEOUT_MPI ?= 900
PYTEST_FLAGS ?=

.PHONY: help setup apt-packages demo gallery test test-serial test-mpi bench ab-refracture studies devito-env

help:
	@sed -n '3,7p' Makefile | sed 's/^# *//'

setup: apt-packages $(STAMP)

# dpkg check only; apt-get runs (update + install) when something is missing
apt-packages:
	@missing=""; \
	for p in $(APT_PACKAGES); do \
	  dpkg -s $$p 2>/dev/null | grep -q '^Status: install ok installed' || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  echo "[setup] installing Debian packages:$$missing"; \
	  $(SUDO) apt-get update && \
	  DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y $$missing; \
	fi

$(PY): | apt-packages
	/usr/bin/python3 -m venv --system-site-packages $(VENV)

$(STAMP): pyproject.toml constraints.txt | $(PY)
	$(PY) -m pip install -c constraints.txt -e .
	touch $@

# The main job: the regularised crack-intersection problem (paper §3.1), then its
# figures, charts, animation and ParaView state.  DEMO_ARGS="--quick" for a 1-minute version.
DEMO      := intersection_regularized
DEMO_OUT  := results/$(DEMO)
DEMO_ARGS ?= --frames 80

demo: setup
	@if [ $(NPROC) -ge 2 ]; then \
	  echo "[demo] $(MPIRUN) -n 2 $(PY) scenarios/$(DEMO).py --out $(DEMO_OUT) $(DEMO_ARGS)"; \
	  $(MPIRUN) -n 2 $(PY) scenarios/$(DEMO).py --out $(DEMO_OUT) $(DEMO_ARGS); \
	else \
	  echo "[demo] $(PY) scenarios/$(DEMO).py --out $(DEMO_OUT) $(DEMO_ARGS) (1 core)"; \
	  $(PY) scenarios/$(DEMO).py --out $(DEMO_OUT) $(DEMO_ARGS); \
	fi
	$(PY) -m hydrofrac.postprocess $(DEMO_OUT)
	@echo "[demo] ParaView:  paraview --state=$(DEMO_OUT)/figures/$(DEMO).pvsm  (or paraview $(DEMO_OUT)/$(DEMO).pvd)"
	@echo "[demo] figures:   $(DEMO_OUT)/figures/energy_sequence.png, mesh_sequence.png (one PNG per frame beside them)"
	@echo "[demo] animation: $(DEMO_OUT)/figures/$(DEMO)_energy.gif"
	@echo "[demo] charts:    $(DEMO_OUT)/figures/charts.png (pressure, energy budget, crack length, contact modes, opening, where the wall time went)"
	@echo "[demo] summary:   $(DEMO_OUT)/summary.json, history: $(DEMO_OUT)/history.csv"

# the README gallery from the full-size runs of the paper's problems on 2 ranks (the
# re-fracture takes about 2 minutes here); GALLERY_ARGS="--quick" for the small versions
GALLERY_RUNS := /tmp/hydrofrac-gallery
GALLERY_ARGS ?=
gallery: setup
	$(MPIRUN) -n 2 $(PY) scenarios/intersection_regularized.py $(GALLERY_ARGS) --frames 120 --out $(GALLERY_RUNS)/reg
	$(MPIRUN) -n 2 $(PY) scenarios/intersection_unregularized.py $(GALLERY_ARGS) --frames 120 --out $(GALLERY_RUNS)/unreg
	$(MPIRUN) -n 2 $(PY) scenarios/refracture.py $(GALLERY_ARGS) --frames 120 --out $(GALLERY_RUNS)/refrac
	$(PY) -m hydrofrac.postprocess.gallery --regularized $(GALLERY_RUNS)/reg --unregularized $(GALLERY_RUNS)/unreg \
	  --refracture $(GALLERY_RUNS)/refrac --out postprocess/gallery

test: setup test-serial test-mpi

test-serial: setup
	timeout $(TEST_TIMEOUT) $(PY) -m pytest -m "not mpi" $(PYTEST_FLAGS)

# pytest exits with 5 when it collects nothing: fine while there are no MPI tests,
# so look first (serially) and run mpirun only if there is something to run.
test-mpi: setup
	@$(PY) -m pytest -m mpi --collect-only -q -p no:cacheprovider >/dev/null; rc=$$?; \
	if [ $$rc -eq 5 ]; then echo "[test] no MPI tests (-m mpi) collected: skipping the 2-rank pass"; \
	elif [ $$rc -ne 0 ]; then echo "[test] collecting the MPI tests failed (exit $$rc)"; exit $$rc; \
	else \
	  echo "[test] $(MPIRUN) -n 2 $(PY) -m pytest -m mpi"; \
	  timeout $(TEST_TIMEOUT_MPI) $(MPIRUN) -n 2 $(PY) -m pytest -m mpi -p no:cacheprovider $(PYTEST_FLAGS); \
	fi

bench: setup
	$(PY) scenarios/benchmark_bulk.py
	$(MPIRUN) -n 2 $(PY) scenarios/benchmark_bulk.py
	$(PY) scenarios/benchmark_interface.py
	$(PY) -m hydrofrac.postprocess.study_contact_stability

# issue 19's re-fracture to 10 ms as it was posed, side by side with the code then (ab93a21,
# from a worktree of its own) on 2 ranks, alternating: that code's scene (an unlimited fluid
# supply, tips stopped 2.9 m from the centre, no branching, microcracks or tip-speed cap) under
# rk4 and ADER; AB_ROUNDS rounds (~3.5 min each here).  docs/benchmarks.md, "A/B against an
# earlier revision"; postprocess/ab.py does any such series
AB_ROUNDS ?= 2
AS_FILED := --pump-rate inf --growth-max-radius 2.9 --growth-branch-speed inf --growth-nucleation-cap 0 \
            --growth-max-speed inf
ab-refracture: setup
	$(PY) -m hydrofrac.postprocess.ab scenarios/refracture.py --base ab93a21 --ranks 2 --rounds $(AB_ROUNDS) \
	  --mpirun "$(MPIRUN)" --args "--frames 40" --variant "rk4=$(AS_FILED) --scheme rk4" \
	  --variant "ader=$(AS_FILED) --scheme ader" --out results/ab_refracture

# the speed-against-accuracy studies (CSV + PNG in postprocess/results; ~10 min on 2 cores)
studies: setup
	$(PY) -m hydrofrac.postprocess.study_work_precision
	$(PY) -m hydrofrac.postprocess.study_time_schemes
	$(PY) -m hydrofrac.postprocess.study_work_precision_cracks
	$(PY) -m hydrofrac.postprocess.study_contact_stability
	$(PY) -m hydrofrac.postprocess.study_contact_regularisation
	$(PY) -m hydrofrac.postprocess.study_crossing
	$(PY) -m hydrofrac.postprocess.study_path_convergence
	$(MPIRUN) -n 2 $(PY) -m hydrofrac.postprocess.study_mesh_grading
	$(PY) -m hydrofrac.postprocess.study_local_time_stepping
	$(PY) -m hydrofrac.postprocess.study_peer_devito

# Devito (the external peer of study_peer_devito) in its own environment: optional, not used by
# make test; Devito 4.8.6 imports with NumPy 1.24 when codepy and cgen are held below 2023
DEVITO_VENV := .venv-devito
devito-env: $(DEVITO_VENV)/.installed
$(DEVITO_VENV)/.installed: postprocess/devito-requirements.txt | apt-packages
	/usr/bin/python3 -m venv $(DEVITO_VENV)
	$(DEVITO_VENV)/bin/python -m pip install -r postprocess/devito-requirements.txt
	touch $@
