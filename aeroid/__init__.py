"""AeroID: flight-vehicle system identification with honest error bars.

The public API is re-exported here; see the README for a tour.
"""

from ._version import __version__
from .data import FlightData, load_flight_test
from .design import ExperimentDesign, design_experiment
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
from .filtering import FilterResult, filter_states
from .frequency import ChannelFrequencyResponse, FrequencyResponseResult, frequency_response
from .identification import IdentificationResult, identify
from .inference import EnsembleRun, InferenceResult, combine_ensembles, infer, infer_ensemble
from .jax_backend import simulate_rk4
from .maneuvers import (
    Chirp,
    Doublet,
    ManeuverFamily,
    Multisine,
    OrthogonalMultisine,
    orthogonal_multisine,
)
from .model import BatchSimulation, Model, SimulationResult, SimulatorModel
from .priors import HalfNormal, LogUniform, Normal, Prior, Uniform
from .propagation import PropagationResult, propagate
from .reporting import report
from .sampler import (
    ChainState,
    SamplerRun,
    autocorrelation_time,
    effective_sample_size,
    ensemble_sampler,
    split_r_hat,
)
from .sensitivity import SensitivityResult, sensitivities
from .validation import OutputMetrics, ValidationResult, validate

__all__ = [
    "AdapterError",
    "AeroidError",
    "BatchSimulation",
    "ChainState",
    "ChannelError",
    "ChannelFrequencyResponse",
    "Chirp",
    "ConfigError",
    "DataFormatError",
    "Doublet",
    "EnsembleRun",
    "ExperimentDesign",
    "FilterError",
    "FilterResult",
    "FlightData",
    "FrequencyResponseResult",
    "HalfNormal",
    "IdentifiabilityWarning",
    "IdentificationError",
    "IdentificationResult",
    "InferenceError",
    "InferenceResult",
    "LogUniform",
    "ManeuverFamily",
    "Model",
    "ModelDefinitionError",
    "Multisine",
    "Normal",
    "OrthogonalMultisine",
    "OutputMetrics",
    "PipelineError",
    "Prior",
    "PropagationResult",
    "SamplerRun",
    "SensitivityResult",
    "SimulationError",
    "SimulationResult",
    "SimulatorModel",
    "StoreError",
    "Uniform",
    "ValidationResult",
    "__version__",
    "autocorrelation_time",
    "combine_ensembles",
    "design_experiment",
    "effective_sample_size",
    "ensemble_sampler",
    "filter_states",
    "frequency_response",
    "identify",
    "infer",
    "infer_ensemble",
    "load_flight_test",
    "orthogonal_multisine",
    "propagate",
    "report",
    "sensitivities",
    "simulate_rk4",
    "split_r_hat",
    "validate",
]
