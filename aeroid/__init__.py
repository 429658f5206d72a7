"""AeroID: flight-vehicle system identification with honest error bars.

The public API is re-exported here; see the README for a tour.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# ``X as X``: an explicit re-export, as type checkers in strict mode require
from ._version import __version__ as __version__
from .errors import AdapterError as AdapterError
from .errors import AeroidError as AeroidError
from .errors import ChannelError as ChannelError
from .errors import ConfigError as ConfigError
from .errors import DataFormatError as DataFormatError
from .errors import FilterError as FilterError
from .errors import IdentifiabilityWarning as IdentifiabilityWarning
from .errors import IdentificationError as IdentificationError
from .errors import InferenceError as InferenceError
from .errors import ModelDefinitionError as ModelDefinitionError
from .errors import OutputError as OutputError
from .errors import PipelineError as PipelineError
from .errors import ResidualDriftWarning as ResidualDriftWarning
from .errors import SimulationError as SimulationError
from .errors import StoreError as StoreError

if TYPE_CHECKING:  # the lazy table below, as type checkers must see it
    from ._logtypes import FlightLog as FlightLog
    from ._logtypes import LogChannel as LogChannel
    from ._logtypes import LogEvent as LogEvent
    from .aircraft import AircraftConstants as AircraftConstants
    from .channel_map import ChannelMap as ChannelMap
    from .channel_map import ChannelSpec as ChannelSpec
    from .channel_map import apply_channel_map as apply_channel_map
    from .channel_map import flight_windows as flight_windows
    from .channel_map import load_mapped as load_mapped
    from .coefficients import coefficients_from_data as coefficients_from_data
    from .compatibility import CompatibilityResult as CompatibilityResult
    from .compatibility import check_compatibility as check_compatibility
    from .data import FlightData as FlightData
    from .data import load_flight_test as load_flight_test
    from .database import AeroDatabase as AeroDatabase
    from .database import FlightCoefficients as FlightCoefficients
    from .database import HeldOutCheck as HeldOutCheck
    from .database import aerodynamic_database as aerodynamic_database
    from .design import ExperimentDesign as ExperimentDesign
    from .design import design_experiment as design_experiment
    from .filtering import FilterResult as FilterResult
    from .filtering import filter_states as filter_states
    from .frequency import ChannelFrequencyResponse as ChannelFrequencyResponse
    from .frequency import FrequencyResponseResult as FrequencyResponseResult
    from .frequency import frequency_response as frequency_response
    from .frequency_domain import FrequencyDomainResult as FrequencyDomainResult
    from .frequency_domain import identify_frequency_domain as identify_frequency_domain
    from .frequency_id import CompositeResponse as CompositeResponse
    from .frequency_id import ResponseChannel as ResponseChannel
    from .frequency_id import TransferFunctionFit as TransferFunctionFit
    from .frequency_id import composite_response as composite_response
    from .frequency_id import fit_transfer_function as fit_transfer_function
    from .handling_qualities import BandwidthResult as BandwidthResult
    from .handling_qualities import EquivalentSystemFit as EquivalentSystemFit
    from .handling_qualities import HandlingQualitiesLevel as HandlingQualitiesLevel
    from .handling_qualities import Margins as Margins
    from .handling_qualities import bandwidth as bandwidth
    from .handling_qualities import bandwidth_level as bandwidth_level
    from .handling_qualities import equivalent_system as equivalent_system
    from .handling_qualities import short_period_level as short_period_level
    from .handling_qualities import stability_margins as stability_margins
    from .identification import IdentificationResult as IdentificationResult
    from .identification import identify as identify
    from .inference import EnsembleRun as EnsembleRun
    from .inference import InferenceResult as InferenceResult
    from .inference import combine_ensembles as combine_ensembles
    from .inference import infer as infer
    from .inference import infer_ensemble as infer_ensemble
    from .jax_backend import simulate_rk4 as simulate_rk4
    from .logs import ChannelListing as ChannelListing
    from .logs import list_channels as list_channels
    from .logs import read_log as read_log
    from .maneuvers import Chirp as Chirp
    from .maneuvers import Doublet as Doublet
    from .maneuvers import ManeuverFamily as ManeuverFamily
    from .maneuvers import Multisine as Multisine
    from .maneuvers import OrthogonalMultisine as OrthogonalMultisine
    from .maneuvers import orthogonal_multisine as orthogonal_multisine
    from .model import BatchSimulation as BatchSimulation
    from .model import Model as Model
    from .model import SimulationResult as SimulationResult
    from .model import SimulatorModel as SimulatorModel
    from .priors import HalfNormal as HalfNormal
    from .priors import LogUniform as LogUniform
    from .priors import Normal as Normal
    from .priors import Prior as Prior
    from .priors import Uniform as Uniform
    from .propagation import PropagationBatch as PropagationBatch
    from .propagation import PropagationResult as PropagationResult
    from .propagation import VectorPropagationResult as VectorPropagationResult
    from .propagation import combine_batches as combine_batches
    from .propagation import propagate as propagate
    from .propagation import propagate_batch as propagate_batch
    from .quality import ChannelQuality as ChannelQuality
    from .quality import DataQualityReport as DataQualityReport
    from .quality import check_data_quality as check_data_quality
    from .regression import RegressionResult as RegressionResult
    from .regression import StepwiseResult as StepwiseResult
    from .regression import StepwiseStep as StepwiseStep
    from .regression import candidate_pool as candidate_pool
    from .regression import equation_error as equation_error
    from .regression import spline_terms as spline_terms
    from .regression import stepwise_regression as stepwise_regression
    from .reporting import report as report
    from .resampling import resample as resample
    from .sampler import ChainState as ChainState
    from .sampler import SamplerRun as SamplerRun
    from .sampler import autocorrelation_time as autocorrelation_time
    from .sampler import effective_sample_size as effective_sample_size
    from .sampler import ensemble_sampler as ensemble_sampler
    from .sampler import split_r_hat as split_r_hat
    from .segmentation import ManeuverWindow as ManeuverWindow
    from .segmentation import SegmentationResult as SegmentationResult
    from .segmentation import segment as segment
    from .sensitivity import SensitivityResult as SensitivityResult
    from .sensitivity import sensitivities as sensitivities
    from .smoothing import differentiate as differentiate
    from .smoothing import optimal_cutoff as optimal_cutoff
    from .smoothing import smooth as smooth
    from .validation import OutputMetrics as OutputMetrics
    from .validation import ValidationResult as ValidationResult
    from .validation import validate as validate

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
    "load_flight_test": ".data",
    "AeroDatabase": ".database",
    "FlightCoefficients": ".database",
    "HeldOutCheck": ".database",
    "aerodynamic_database": ".database",
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

    def __getattr__(name: str) -> object:
        from importlib import import_module

        module = _LAZY.get(name)
        if module is None:
            raise AttributeError(f"module 'aeroid' has no attribute {name!r}")
        value = getattr(import_module(module, __name__), name)
        globals()[name] = value
        return value

    def __dir__() -> list[str]:
        return list(__all__)


# the public names: the version, the errors and the lazy table, each listed once above
__all__ = sorted(
    {"__version__", *_LAZY}
    | {n for n, v in globals().items() if getattr(v, "__module__", None) == "aeroid.errors"}
)
del annotations, TYPE_CHECKING  # tools of this module, not names of the package
