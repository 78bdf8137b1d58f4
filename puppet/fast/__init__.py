"""FAST (Jacobson et al. 2012): reduced ARAP in the linear-blend-skinning subspace V' = M T.

    model = FastModel(V, F, W, clusters=50, extra_weights=0, energy="spokes_and_rims")  # per rig
    pattern = Pattern(full=(0,), relative=((1, 0, pivot),), positional=())
    solver = model.solver(pattern)                 # per pattern: factor (refactor), PatternError
    values = pattern.values()                      # per frame: fill in place
    T = model.rest_T()                             # (4m, 3) float32, handle j in rows 4j..4j+3
    stats = solver.solve(values, T, iterations=10)  # T updated in place; native, GIL released

Modules: weights (validation, extra weights), clusters (k-means in weight space), energy
(reduced matrices per energy type), factor (per-pattern global step), solver (facade over
puppet._native.FastSolver), model (precompute and its cache), pattern (constraints).
"""

from puppet.fast.errors import FastError, MeshError, PatternError, WeightsError
from puppet.fast.pattern import Pattern, Values

# The solver and the precompute load the native module: imported on first use, so that the
# pure-numpy parts (pattern, energy names, errors) can be imported without a compiled solver
# (the rig needs Pattern and ENERGIES; reading a rig must not need puppet._native).
_LAZY = {"FastModel": "puppet.fast.model", "Solver": "puppet.fast.solver",
         "Dynamics": "puppet.fast.solver"}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'puppet.fast' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


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
