"""FAST (Jacobson et al. 2012): reduced ARAP in the linear-blend-skinning subspace V' = M T."""

from puppet.fast.errors import FastError, MeshError, PatternError, WeightsError
from puppet.fast.model import FastModel
from puppet.fast.pattern import Pattern, Values
from puppet.fast.solver import Dynamics, Solver

__all__ = [
    "FastModel",
    "Solver",
    "Dynamics",
    "Pattern",
    "Values",
    "FastError",
    "MeshError",
    "WeightsError",
    "PatternError",
]
