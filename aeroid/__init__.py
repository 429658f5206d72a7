"""AeroID: flight-vehicle system identification with honest error bars.

The public API is re-exported here; see the README for a tour.
"""

from ._version import __version__
from .data import FlightData, load_flight_test
from .errors import (
    AdapterError,
    AeroidError,
    ChannelError,
    ConfigError,
    DataFormatError,
    FilterError,
    IdentifiabilityWarning,
    IdentificationError,
    InferenceError,
    ModelDefinitionError,
    PipelineError,
    SimulationError,
    StoreError,
)
from .model import BatchSimulation, Model, SimulationResult, SimulatorModel

__all__ = [
    "AdapterError",
    "AeroidError",
    "BatchSimulation",
    "ChannelError",
    "ConfigError",
    "DataFormatError",
    "FilterError",
    "FlightData",
    "IdentifiabilityWarning",
    "IdentificationError",
    "InferenceError",
    "Model",
    "ModelDefinitionError",
    "PipelineError",
    "SimulationError",
    "SimulationResult",
    "SimulatorModel",
    "StoreError",
    "__version__",
    "load_flight_test",
]
