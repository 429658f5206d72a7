"""AeroID: flight-vehicle system identification with honest error bars.

The public API is re-exported here; see the README for a tour.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from ._version import __version__
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
    OutputError,
    PipelineError,
    SimulationError,
    StoreError,
)

if TYPE_CHECKING:
    from .aircraft import AircraftConstants
    from .coefficients import coefficients_from_data
    from .compatibility import CompatibilityResult, check_compatibility
    from .data import FlightData, load_flight_test
    from .design import ExperimentDesign, design_experiment
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
    from .propagation import (
        PropagationBatch,
        PropagationResult,
        VectorPropagationResult,
        combine_batches,
        propagate,
        propagate_batch,
    )
    from .regression import (
        RegressionResult,
        StepwiseResult,
        StepwiseStep,
        candidate_pool,
        equation_error,
        spline_terms,
        stepwise_regression,
    )
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
    from .smoothing import differentiate, optimal_cutoff, smooth
    from .validation import OutputMetrics, ValidationResult, validate

# The rest of the public API is imported on first use: `import aeroid` (and with it
# the `aeroid` command, the pipeline and every worker it spawns) then pays only
# for the modules it touches, not for all of SciPy.
_LAZY = {
    "AircraftConstants": ".aircraft",
    "FlightData": ".data",
    "load_flight_test": ".data",
    "coefficients_from_data": ".coefficients",
    "CompatibilityResult": ".compatibility",
    "check_compatibility": ".compatibility",
    "ExperimentDesign": ".design",
    "design_experiment": ".design",
    "FilterResult": ".filtering",
    "filter_states": ".filtering",
    "ChannelFrequencyResponse": ".frequency",
    "FrequencyResponseResult": ".frequency",
    "frequency_response": ".frequency",
    "IdentificationResult": ".identification",
    "identify": ".identification",
    "EnsembleRun": ".inference",
    "InferenceResult": ".inference",
    "combine_ensembles": ".inference",
    "infer": ".inference",
    "infer_ensemble": ".inference",
    "simulate_rk4": ".jax_backend",
    "Chirp": ".maneuvers",
    "Doublet": ".maneuvers",
    "ManeuverFamily": ".maneuvers",
    "Multisine": ".maneuvers",
    "OrthogonalMultisine": ".maneuvers",
    "orthogonal_multisine": ".maneuvers",
    "BatchSimulation": ".model",
    "Model": ".model",
    "SimulationResult": ".model",
    "SimulatorModel": ".model",
    "HalfNormal": ".priors",
    "LogUniform": ".priors",
    "Normal": ".priors",
    "Prior": ".priors",
    "Uniform": ".priors",
    "PropagationBatch": ".propagation",
    "PropagationResult": ".propagation",
    "VectorPropagationResult": ".propagation",
    "combine_batches": ".propagation",
    "propagate": ".propagation",
    "propagate_batch": ".propagation",
    "RegressionResult": ".regression",
    "StepwiseResult": ".regression",
    "StepwiseStep": ".regression",
    "candidate_pool": ".regression",
    "equation_error": ".regression",
    "spline_terms": ".regression",
    "stepwise_regression": ".regression",
    "report": ".reporting",
    "ChainState": ".sampler",
    "SamplerRun": ".sampler",
    "autocorrelation_time": ".sampler",
    "effective_sample_size": ".sampler",
    "ensemble_sampler": ".sampler",
    "split_r_hat": ".sampler",
    "SensitivityResult": ".sensitivity",
    "sensitivities": ".sensitivity",
    "differentiate": ".smoothing",
    "optimal_cutoff": ".smoothing",
    "smooth": ".smoothing",
    "OutputMetrics": ".validation",
    "ValidationResult": ".validation",
    "validate": ".validation",
}


if not TYPE_CHECKING:  # type checkers see the imports above, and no catch-all

    def __getattr__(name: str) -> Any:
        module = _LAZY.get(name)
        if module is None:
            raise AttributeError(f"module 'aeroid' has no attribute {name!r}")
        value = getattr(importlib.import_module(module, __name__), name)
        globals()[name] = value
        return value

    def __dir__() -> list[str]:
        return sorted(set(globals()) | set(__all__))


__all__ = [
    "AdapterError",
    "AeroidError",
    "AircraftConstants",
    "BatchSimulation",
    "ChainState",
    "ChannelError",
    "ChannelFrequencyResponse",
    "Chirp",
    "CompatibilityResult",
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
    "OutputError",
    "OutputMetrics",
    "PipelineError",
    "Prior",
    "PropagationBatch",
    "PropagationResult",
    "RegressionResult",
    "SamplerRun",
    "SensitivityResult",
    "SimulationError",
    "SimulationResult",
    "SimulatorModel",
    "StepwiseResult",
    "StepwiseStep",
    "StoreError",
    "Uniform",
    "ValidationResult",
    "VectorPropagationResult",
    "__version__",
    "autocorrelation_time",
    "candidate_pool",
    "check_compatibility",
    "coefficients_from_data",
    "combine_batches",
    "combine_ensembles",
    "design_experiment",
    "differentiate",
    "effective_sample_size",
    "ensemble_sampler",
    "equation_error",
    "filter_states",
    "frequency_response",
    "identify",
    "infer",
    "infer_ensemble",
    "load_flight_test",
    "optimal_cutoff",
    "orthogonal_multisine",
    "propagate",
    "propagate_batch",
    "report",
    "sensitivities",
    "simulate_rk4",
    "smooth",
    "spline_terms",
    "split_r_hat",
    "stepwise_regression",
    "validate",
]
