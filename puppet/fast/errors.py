"""Typed errors of the FAST solver; each names the input and field at fault."""

from __future__ import annotations


class FastError(ValueError):
    """Base class: bad input to the FAST precompute or solve."""


class MeshError(FastError):
    """The mesh (V, F or tets) is unusable: wrong shape, non-finite, bad indices."""


class WeightsError(FastError):
    """The weight matrix W is unusable: wrong shape, negative or non-summing rows."""


class PatternError(FastError):
    """A constraint pattern is malformed or leaves the solve undetermined."""


class ValuesError(FastError):
    """Per-frame constraint values do not fit the pattern (shape, dtype, NaN/inf)."""
