"""Semismooth Newton for the complementarity systems of :mod:`ngcontact.algebra`."""
from .loop import IterationRecord, NewtonOptions, NewtonResult, Reference, decoupled_newton, semismooth_newton

__all__ = ["NewtonOptions", "IterationRecord", "NewtonResult", "Reference", "semismooth_newton", "decoupled_newton"]
