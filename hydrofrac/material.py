"""Isotropic linear-elastic materials (plane strain).

One place for every derived constant: Lamé parameters, wave speeds and
impedances are computed once here and used by the forms, the Riemann
solutions and the tests (model.md §1).
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field


def plane_strain_kappa(lam, mu):
    """kappa = lambda / (2 (lambda + mu)): the plane-strain compliance is
    C^{-1}:sigma = (sigma - kappa tr(sigma) I) / (2 mu), and s_zz = kappa (s_xx + s_yy) (model §1).
    Works on numbers, numpy arrays and UFL expressions."""
    return lam / (2 * (lam + mu))


@dataclass(frozen=True)
class Material:
    """Isotropic elastic solid in plane strain.

    Parameters
    ----------
    E : Young's modulus [Pa], > 0
    nu : Poisson's ratio, in (-1, 0.5)
    rho : density [kg/m^3], > 0
    name : label used in messages and output
    """

    E: float
    nu: float
    rho: float
    name: str = "rock"
    lam: float = field(init=False)
    mu: float = field(init=False)

    def __post_init__(self):
        for key in ("E", "nu", "rho"):
            val = getattr(self, key)
            if not isinstance(val, numbers.Real) or isinstance(val, bool) or not math.isfinite(val):
                raise ValueError(f"material '{self.name}': {key} must be a finite number; got {val!r}")
            object.__setattr__(self, key, float(val))  # any real type (numpy float32, int64, ...)
        if self.E <= 0:
            raise ValueError(f"material '{self.name}': E must be > 0 (Pa); got {self.E}")
        if not -1.0 < self.nu < 0.5:
            raise ValueError(f"material '{self.name}': nu must be in (-1, 0.5); got {self.nu}")
        if self.rho <= 0:
            raise ValueError(f"material '{self.name}': rho must be > 0 (kg/m^3); got {self.rho}")
        object.__setattr__(self, "lam", self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu)))
        object.__setattr__(self, "mu", self.E / (2 * (1 + self.nu)))

    @property
    def cd(self) -> float:
        """Dilatational (P) wave speed sqrt((lam + 2 mu)/rho)."""
        return math.sqrt((self.lam + 2 * self.mu) / self.rho)

    @property
    def cs(self) -> float:
        """Shear (S) wave speed sqrt(mu/rho)."""
        return math.sqrt(self.mu / self.rho)

    @property
    def cR(self) -> float:
        """Rayleigh wave speed: the root xi = c_R/c_s in (0, 1) of
        (2 - xi^2)^2 = 4 sqrt(1 - xi^2 c_s^2/c_d^2) sqrt(1 - xi^2) (bisection to round-off;
        1663 m/s for the paper's rock)."""
        k2 = (self.cs / self.cd) ** 2

        def f(x):
            return (2 - x * x) ** 2 - 4 * math.sqrt(1 - x * x * k2) * math.sqrt(1 - x * x)
        lo, hi = 1e-6, 1.0 - 1e-15  # f(lo) < 0 < f(hi) for nu in (-1, 0.5)
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
        return 0.5 * (lo + hi) * self.cs

    @property
    def Zd(self) -> float:
        """Dilatational impedance rho c_d (normal component, index 1)."""
        return self.rho * self.cd

    @property
    def Zs(self) -> float:
        """Shear impedance rho c_s (tangential component, index 2)."""
        return self.rho * self.cs


#: The paper's rock (§3): E = 20 GPa, nu = 0.2, rho = 2500 kg/m^3.
ROCK = Material(E=20e9, nu=0.2, rho=2500.0, name="rock")

#: Confining pressure of the paper's problems [Pa]; sigma_0 = -p0 I.
CONFINEMENT = 2.425e6
