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
    ResidualDriftWarning,
    SimulationError,
    StoreError,
)

if TYPE_CHECKING:
    from ._logtypes import FlightLog, LogChannel, LogEvent
    from .aircraft import AircraftConstants
    from .channel_map import ChannelMap, ChannelSpec, apply_channel_map, flight_windows, load_mapped
    from .coefficients import coefficients_from_data
    from .compatibility import CompatibilityResult, check_compatibility
    from .data import FlightData, load_flight_test
    from .database import AeroDatabase, FlightCoefficients, HeldOutCheck, aerodynamic_database
    from .design import ExperimentDesign, design_experiment
    from .filtering import FilterResult, filter_states
    from .frequency import ChannelFrequencyResponse, FrequencyResponseResult, frequency_response
    from .frequency_domain import FrequencyDomainResult, identify_frequency_domain
    from .frequency_id import (
        CompositeResponse,
        ResponseChannel,
        TransferFunctionFit,
        composite_response,
        fit_transfer_function,
    )
    from .handling_qualities import (
        BandwidthResult,
        EquivalentSystemFit,
        HandlingQualitiesLevel,
        Margins,
        bandwidth,
        bandwidth_level,
        equivalent_system,
        short_period_level,
        stability_margins,
    )
    from .identification import IdentificationResult, identify
    from .inference import EnsembleRun, InferenceResult, combine_ensembles, infer, infer_ensemble
    from .jax_backend import simulate_rk4
    from .logs import ChannelListing, list_channels, read_log
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
    from .quality import ChannelQuality, DataQualityReport, check_data_quality
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
    from .resampling import resample
    from .sampler import (
        ChainState,
        SamplerRun,
        autocorrelation_time,
        effective_sample_size,
        ensemble_sampler,
        split_r_hat,
    )
    from .segmentation import ManeuverWindow, SegmentationResult, segment
    from .sensitivity import SensitivityResult, sensitivities
    from .smoothing import differentiate, optimal_cutoff, smooth
    from .validation import OutputMetrics, ValidationResult, validate

# The rest of the public API is imported on first use: `import aeroid` (and with it
# the `aeroid` command, the pipeline and every worker it spawns) then pays only
# for the modules it touches, not for all of SciPy.
_LAZY = {
    "AircraftConstants": ".aircraft",
    "ChannelMap": ".channel_map",
    "ChannelSpec": ".channel_map",
    "apply_channel_map": ".channel_map",
    "flight_windows": ".channel_map",
    "load_mapped": ".channel_map",
    "FlightData": ".data",
    "AeroDatabase": ".database",
    "FlightCoefficients": ".database",
    "HeldOutCheck": ".database",
    "aerodynamic_database": ".database",
    "load_flight_test": ".data",
    "FlightLog": "._logtypes",
    "LogChannel": "._logtypes",
    "LogEvent": "._logtypes",
    "ChannelListing": ".logs",
    "list_channels": ".logs",
    "read_log": ".logs",
    "ChannelQuality": ".quality",
    "DataQualityReport": ".quality",
    "check_data_quality": ".quality",
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
    "FrequencyDomainResult": ".frequency_domain",
    "identify_frequency_domain": ".frequency_domain",
    "CompositeResponse": ".frequency_id",
    "ResponseChannel": ".frequency_id",
    "TransferFunctionFit": ".frequency_id",
    "composite_response": ".frequency_id",
    "fit_transfer_function": ".frequency_id",
    "BandwidthResult": ".handling_qualities",
    "EquivalentSystemFit": ".handling_qualities",
    "HandlingQualitiesLevel": ".handling_qualities",
    "bandwidth_level": ".handling_qualities",
    "short_period_level": ".handling_qualities",
    "Margins": ".handling_qualities",
    "bandwidth": ".handling_qualities",
    "equivalent_system": ".handling_qualities",
    "stability_margins": ".handling_qualities",
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
    "resample": ".resampling",
    "ChainState": ".sampler",
    "SamplerRun": ".sampler",
    "autocorrelation_time": ".sampler",
    "effective_sample_size": ".sampler",
    "ensemble_sampler": ".sampler",
    "split_r_hat": ".sampler",
    "ManeuverWindow": ".segmentation",
    "SegmentationResult": ".segmentation",
    "segment": ".segmentation",
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
    "AeroDatabase",
    "AeroidError",
    "AircraftConstants",
    "BandwidthResult",
    "BatchSimulation",
    "ChainState",
    "ChannelError",
    "ChannelFrequencyResponse",
    "ChannelListing",
    "ChannelMap",
    "ChannelQuality",
    "ChannelSpec",
    "Chirp",
    "CompatibilityResult",
    "CompositeResponse",
    "ConfigError",
    "DataFormatError",
    "DataQualityReport",
    "Doublet",
    "EnsembleRun",
    "EquivalentSystemFit",
    "ExperimentDesign",
    "FilterError",
    "FilterResult",
    "FlightCoefficients",
    "FlightData",
    "FlightLog",
    "FrequencyDomainResult",
    "FrequencyResponseResult",
    "HalfNormal",
    "HandlingQualitiesLevel",
    "HeldOutCheck",
    "IdentifiabilityWarning",
    "IdentificationError",
    "IdentificationResult",
    "InferenceError",
    "InferenceResult",
    "LogChannel",
    "LogEvent",
    "LogUniform",
    "ManeuverFamily",
    "ManeuverWindow",
    "Margins",
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
    "ResidualDriftWarning",
    "ResponseChannel",
    "SamplerRun",
    "SegmentationResult",
    "SensitivityResult",
    "SimulationError",
    "SimulationResult",
    "SimulatorModel",
    "StepwiseResult",
    "StepwiseStep",
    "StoreError",
    "TransferFunctionFit",
    "Uniform",
    "ValidationResult",
    "VectorPropagationResult",
    "__version__",
    "aerodynamic_database",
    "apply_channel_map",
    "autocorrelation_time",
    "bandwidth",
    "bandwidth_level",
    "candidate_pool",
    "check_compatibility",
    "check_data_quality",
    "coefficients_from_data",
    "combine_batches",
    "combine_ensembles",
    "composite_response",
    "design_experiment",
    "differentiate",
    "effective_sample_size",
    "ensemble_sampler",
    "equation_error",
    "equivalent_system",
    "filter_states",
    "fit_transfer_function",
    "flight_windows",
    "frequency_response",
    "identify",
    "identify_frequency_domain",
    "infer",
    "infer_ensemble",
    "list_channels",
    "load_flight_test",
    "load_mapped",
    "optimal_cutoff",
    "orthogonal_multisine",
    "propagate",
    "propagate_batch",
    "read_log",
    "report",
    "resample",
    "segment",
    "sensitivities",
    "short_period_level",
    "simulate_rk4",
    "smooth",
    "spline_terms",
    "split_r_hat",
    "stability_margins",
    "stepwise_regression",
    "validate",
]
