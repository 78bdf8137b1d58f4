"""Typed errors of the FAST solver; each names the input and field at fault."""

from __future__ import annotations

from puppet.errors import PuppetError


class FastError(PuppetError, ValueError):
    """Base class: bad input to the FAST precompute or solve."""


class MeshError(FastError):
    """The mesh (V, F or tets) is unusable: wrong shape, non-finite, bad indices."""


class WeightsError(FastError):
    """The weight matrix W is unusable: wrong shape, negative or non-summing rows."""


class PatternError(FastError):
    """A constraint pattern is malformed or leaves the solve undetermined."""


# Per-frame values are checked in native code (no Python on the per-frame path): wrong dtype or
# layout raises TypeError, wrong counts or NaN/inf raise ValueError naming the field ("values.full").
