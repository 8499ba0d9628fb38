"""hydrofrac: hydraulic fracturing with an interfacial damage/contact model on DG elastodynamics."""
from .material import CONFINEMENT, ROCK, Material  # noqa: F401

__version__ = "0.1.0"
