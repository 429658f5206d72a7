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
from .filtering import FilterResult, filter_states
from .identification import IdentificationResult, identify
from .jax_backend import simulate_rk4
from .propagation import PropagationResult, propagate
from .reporting import report
from .validation import OutputMetrics, ValidationResult, validate
from .model import BatchSimulation, Model, SimulationResult, SimulatorModel
from .design import ExperimentDesign, design_experiment
from .frequency import ChannelFrequencyResponse, FrequencyResponseResult, frequency_response
from .maneuvers import (
    Chirp,
    Doublet,
    ManeuverFamily,
    Multisine,
    OrthogonalMultisine,
    orthogonal_multisine,
)
from .sensitivity import SensitivityResult, sensitivities
from .inference import EnsembleRun, InferenceResult, combine_ensembles, infer, infer_ensemble
from .priors import HalfNormal, LogUniform, Normal, Prior, Uniform
from .sampler import (
    ChainState,
    SamplerRun,
    autocorrelation_time,
    effective_sample_size,
    ensemble_sampler,
    split_r_hat,
)

__all__ = [
    "ChannelFrequencyResponse",
    "Chirp",
    "Doublet",
    "ExperimentDesign",
    "FrequencyResponseResult",
    "ManeuverFamily",
    "Multisine",
    "OrthogonalMultisine",
    "SensitivityResult",
    "design_experiment",
    "frequency_response",
    "orthogonal_multisine",
    "sensitivities",
    "ChainState",
    "EnsembleRun",
    "HalfNormal",
    "InferenceResult",
    "LogUniform",
    "Normal",
    "Prior",
    "SamplerRun",
    "Uniform",
    "autocorrelation_time",
    "combine_ensembles",
    "effective_sample_size",
    "ensemble_sampler",
    "infer",
    "infer_ensemble",
    "split_r_hat",
    "AdapterError",
    "AeroidError",
    "BatchSimulation",
    "ChannelError",
    "ConfigError",
    "DataFormatError",
    "FilterError",
    "FilterResult",
    "FlightData",
    "IdentifiabilityWarning",
    "IdentificationError",
    "IdentificationResult",
    "InferenceError",
    "Model",
    "ModelDefinitionError",
    "PipelineError",
    "SimulationError",
    "SimulationResult",
    "SimulatorModel",
    "StoreError",
    "OutputMetrics",
    "PropagationResult",
    "ValidationResult",
    "__version__",
    "propagate",
    "report",
    "validate",
    "filter_states",
    "identify",
    "load_flight_test",
    "simulate_rk4",
]
