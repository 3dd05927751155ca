"""The non-finite guard lives in ``toolkit.loops.guard``, with what every training loop shares; these names
stay importable here for the avatar loop and the benchmarks until they import them from there."""

from trioman.toolkit.loops.guard import NonFiniteError, StepGuard, check_weights

__all__ = ["NonFiniteError", "StepGuard", "check_weights"]
