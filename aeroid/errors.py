"""Exception and warning classes raised by AeroID."""

from __future__ import annotations

__all__ = [
    "AdapterError",
    "AeroidError",
    "ChannelError",
    "ConfigError",
    "DataFormatError",
    "FilterError",
    "IdentifiabilityWarning",
    "IdentificationError",
    "InferenceError",
    "ModelDefinitionError",
    "OutputError",
    "PipelineError",
    "PropagationError",
    "SimulationError",
    "StoreError",
]


class AeroidError(Exception):
    """Base class of every error AeroID raises on purpose."""


class ModelDefinitionError(AeroidError, ValueError):
    """A `Model` is malformed: bad names, or dynamics that cannot be evaluated."""


class DataFormatError(AeroidError, ValueError):
    """Flight data or a data file is malformed (NaN, bad time axis, bad cell)."""


class ChannelError(AeroidError, KeyError):
    """A channel the model or the caller needs is not in the data."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0]) if self.args else ""


class SimulationError(AeroidError, RuntimeError):
    """Integration of the model failed or diverged."""


class IdentificationError(AeroidError, ValueError):
    """Parameter identification cannot be set up or run."""


class FilterError(AeroidError, RuntimeError):
    """Kalman filtering failed (for example a covariance lost positive definiteness)."""


class InferenceError(AeroidError, RuntimeError):
    """Bayesian inference cannot be set up or run."""


class AdapterError(AeroidError, RuntimeError):
    """An external simulator adapter is unavailable or misconfigured."""


class PropagationError(AeroidError, ValueError):
    """Monte Carlo propagation cannot run (no usable draws, bad arguments)."""


class OutputError(AeroidError, OSError):
    """A report or other output file cannot be written where it was asked for."""


class PipelineError(AeroidError, RuntimeError):
    """The campaign pipeline cannot run a task."""


class ConfigError(PipelineError, ValueError):
    """A campaign configuration file is invalid."""


class StoreError(PipelineError):
    """A result store entry is missing, corrupt or cannot be written."""


class IdentifiabilityWarning(UserWarning):
    """The data cannot separate some parameters; the result is flagged."""


class ResidualDriftWarning(UserWarning):
    """Residuals of some outputs drift like a random walk over the record with no bias
    estimated on them, which widens the coloured error bars.

    The message names the parameter that widens most. An output bias absorbs a
    constant offset; turbulence or unmodelled slow dynamics (a wandering offset)
    want process noise, that is filter error.

    Attributes
    ----------
    outputs : tuple of str
        The drifting outputs.
    widening : float
        The largest ratio of a coloured to a white standard error.
    """

    def __init__(self, message: str, outputs: tuple[str, ...] = (), widening: float = 0.0):
        super().__init__(message)
        self.outputs = tuple(outputs)
        self.widening = float(widening)
