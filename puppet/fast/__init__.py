"""FAST (Jacobson et al. 2012): reduced ARAP in the linear-blend-skinning subspace V' = M T."""

from puppet.fast.pattern import Pattern, Values

__all__ = ["Pattern", "Values"]
