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


def checkpoint_load_error(err: BaseException) -> tuple[bool, str]:
    """What ``torch.load(..., weights_only=True)`` failing with ``err`` says of the file, in
    one line: ``(True, text)`` when the file holds an object other than tensors and plain
    values (a pickled class, refused because unpickling it could run code), ``(False, text)``
    when it is damaged or no torch file (torch's several-line message cut to its cause)."""
    text = str(err)
    if "Weights only load failed" in text:
        lines = [ln.strip() for ln in text.splitlines()[1:] if ln.strip()]
        # torch names a pickled class as a GLOBAL ("Unsupported global: GLOBAL numpy...",
        # "Trying to load unsupported GLOBAL posix.system ..."), damage otherwise
        named = next((ln for ln in lines if "GLOBAL" in ln), None)
        if named is not None:
            return True, (
                "it holds objects other than tensors and plain values, which are not loaded "
                f"(unpickling them could run code: {named.split('. ')[0][:200]})"
            )
        after = text.split("WeightsUnpickler error:", 1)[1:]  # its cause, when it names one
        detail = after[0].strip().splitlines()[0].strip() if after and after[0].strip() else ""
        return False, f"UnpicklingError: {detail[:200] or 'not a torch checkpoint'}"
    first = text.strip().splitlines()[0] if text.strip() else ""
    return False, f"{type(err).__name__}: {first[:300]}"
