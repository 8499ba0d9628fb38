"""Continuous-Galerkin comparison solvers of the work-precision studies (not part of the model)."""
