"""Typed exceptions and warning categories used across iplanner_torch.

Every error raised on bad input derives from :class:`IPlannerError`, so callers can catch the
whole family at once, and names what was expected and what was got.
"""

from __future__ import annotations


class IPlannerError(Exception):
    """Base class of every error raised by iplanner_torch on bad input or state."""


class DataError(IPlannerError, ValueError):
    """A dataset file or demonstration is malformed (names the file and the field)."""


class ShapeError(IPlannerError, ValueError):
    """A tensor has the wrong shape, dtype or device at a public entry point."""


class ConfigError(IPlannerError, ValueError):
    """A configuration value is missing, unknown or out of range."""


class CheckpointError(IPlannerError, RuntimeError):
    """A checkpoint is missing, corrupt, or incompatible with the requested use."""


class PlanningError(IPlannerError, RuntimeError):
    """The planner could not produce a trajectory (and could not degrade gracefully)."""


class NumericalWarning(UserWarning):
    """Numerical trouble that was handled (jitter added, a solver did not converge, ...)."""


class DataWarning(UserWarning):
    """Input data was degraded but usable (NaN joints imputed, frames dropped, ...)."""


class ConfigWarning(UserWarning):
    """A setting is valid but probably not what was meant (it is used as given)."""
