"""AeroID: flight-vehicle system identification with honest error bars.

The public API is re-exported here; see the README for a tour.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

# ``X as X``: an explicit re-export, as type checkers in strict mode require
from . import _aliases
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
from .errors import PropagationError as PropagationError
from .errors import ResidualDriftWarning as ResidualDriftWarning
from .errors import SimulationError as SimulationError
from .errors import StoreError as StoreError

if TYPE_CHECKING:  # the lazy table below, as type checkers must see it
    from .estimation.compatibility import CompatibilityResult as CompatibilityResult
    from .estimation.compatibility import check_compatibility as check_compatibility
    from .estimation.filtering import FilterResult as FilterResult
    from .estimation.filtering import filter_states as filter_states
    from .estimation.identification import IdentificationResult as IdentificationResult
    from .estimation.identification import identify as identify
    from .estimation.orthogonal_functions import (
        OrthogonalFunctionResult as OrthogonalFunctionResult,
    )
    from .estimation.orthogonal_functions import (
        orthogonal_function_model as orthogonal_function_model,
    )
    from .estimation.recursive_estimation import RecursiveResult as RecursiveResult
    from .estimation.recursive_estimation import (
        recursive_least_squares as recursive_least_squares,
    )
    from .estimation.regression import RegressionResult as RegressionResult
    from .estimation.regression import StepwiseResult as StepwiseResult
    from .estimation.regression import StepwiseStep as StepwiseStep
    from .estimation.regression import candidate_pool as candidate_pool
    from .estimation.regression import equation_error as equation_error
    from .estimation.regression import spline_terms as spline_terms
    from .estimation.regression import stepwise_regression as stepwise_regression
    from .frequency.frequency_domain import FrequencyDomainResult as FrequencyDomainResult
    from .frequency.frequency_domain import identify_frequency_domain as identify_frequency_domain
    from .frequency.frequency_id import CompositeResponse as CompositeResponse
    from .frequency.frequency_id import ResponseChannel as ResponseChannel
    from .frequency.frequency_id import TransferFunctionFit as TransferFunctionFit
    from .frequency.frequency_id import composite_response as composite_response
    from .frequency.frequency_id import fit_transfer_function as fit_transfer_function
    from .frequency.handling_qualities import BandwidthResult as BandwidthResult
    from .frequency.handling_qualities import EquivalentSystemFit as EquivalentSystemFit
    from .frequency.handling_qualities import HandlingQualitiesLevel as HandlingQualitiesLevel
    from .frequency.handling_qualities import Margins as Margins
    from .frequency.handling_qualities import bandwidth as bandwidth
    from .frequency.handling_qualities import bandwidth_level as bandwidth_level
    from .frequency.handling_qualities import equivalent_system as equivalent_system
    from .frequency.handling_qualities import short_period_level as short_period_level
    from .frequency.handling_qualities import stability_margins as stability_margins
    from .frequency.response import ChannelFrequencyResponse as ChannelFrequencyResponse
    from .frequency.response import FrequencyResponseResult as FrequencyResponseResult
    from .frequency.response import frequency_response as frequency_response
    from .io._logtypes import FlightLog as FlightLog
    from .io._logtypes import LogChannel as LogChannel
    from .io._logtypes import LogEvent as LogEvent
    from .io.channel_map import ChannelMap as ChannelMap
    from .io.channel_map import ChannelSpec as ChannelSpec
    from .io.channel_map import apply_channel_map as apply_channel_map
    from .io.channel_map import flight_windows as flight_windows
    from .io.channel_map import load_mapped as load_mapped
    from .io.data import FlightData as FlightData
    from .io.data import load_flight_test as load_flight_test
    from .io.logs import ChannelListing as ChannelListing
    from .io.logs import list_channels as list_channels
    from .io.logs import read_log as read_log
    from .io.quality import ChannelQuality as ChannelQuality
    from .io.quality import DataQualityReport as DataQualityReport
    from .io.quality import check_data_quality as check_data_quality
    from .io.resampling import resample as resample
    from .io.segmentation import ManeuverWindow as ManeuverWindow
    from .io.segmentation import SegmentationResult as SegmentationResult
    from .io.segmentation import segment as segment
    from .io.smoothing import differentiate as differentiate
    from .io.smoothing import optimal_cutoff as optimal_cutoff
    from .io.smoothing import smooth as smooth
    from .models.aircraft import AircraftConstants as AircraftConstants
    from .models.coefficients import coefficients_from_data as coefficients_from_data
    from .models.jax_backend import simulate_rk4 as simulate_rk4
    from .models.model import BatchSimulation as BatchSimulation
    from .models.model import Model as Model
    from .models.model import SimulationResult as SimulationResult
    from .models.model import SimulatorModel as SimulatorModel
    from .reports.reporting import report as report
    from .uncertainty.database import AeroDatabase as AeroDatabase
    from .uncertainty.database import FlightCoefficients as FlightCoefficients
    from .uncertainty.database import HeldOutCheck as HeldOutCheck
    from .uncertainty.database import aerodynamic_database as aerodynamic_database
    from .uncertainty.design import ExperimentDesign as ExperimentDesign
    from .uncertainty.design import design_experiment as design_experiment
    from .uncertainty.inference import EnsembleRun as EnsembleRun
    from .uncertainty.inference import InferenceResult as InferenceResult
    from .uncertainty.inference import combine_ensembles as combine_ensembles
    from .uncertainty.inference import infer as infer
    from .uncertainty.inference import infer_ensemble as infer_ensemble
    from .uncertainty.maneuvers import Chirp as Chirp
    from .uncertainty.maneuvers import Doublet as Doublet
    from .uncertainty.maneuvers import ManeuverFamily as ManeuverFamily
    from .uncertainty.maneuvers import Multisine as Multisine
    from .uncertainty.maneuvers import Multistep as Multistep
    from .uncertainty.orthogonal_multisines import OrthogonalMultisine as OrthogonalMultisine
    from .uncertainty.orthogonal_multisines import orthogonal_multisine as orthogonal_multisine
    from .uncertainty.prediction import PredictionResult as PredictionResult
    from .uncertainty.priors import HalfNormal as HalfNormal
    from .uncertainty.priors import LogUniform as LogUniform
    from .uncertainty.priors import Normal as Normal
    from .uncertainty.priors import Prior as Prior
    from .uncertainty.priors import Uniform as Uniform
    from .uncertainty.propagation import PropagationBatch as PropagationBatch
    from .uncertainty.propagation import PropagationResult as PropagationResult
    from .uncertainty.propagation import VectorPropagationResult as VectorPropagationResult
    from .uncertainty.propagation import combine_batches as combine_batches
    from .uncertainty.propagation import propagate as propagate
    from .uncertainty.propagation import propagate_batch as propagate_batch
    from .uncertainty.sampler import ChainState as ChainState
    from .uncertainty.sampler import SamplerRun as SamplerRun
    from .uncertainty.sampler import autocorrelation_time as autocorrelation_time
    from .uncertainty.sampler import effective_sample_size as effective_sample_size
    from .uncertainty.sampler import ensemble_sampler as ensemble_sampler
    from .uncertainty.sampler import split_r_hat as split_r_hat
    from .uncertainty.sensitivity import SensitivityResult as SensitivityResult
    from .uncertainty.sensitivity import sensitivities as sensitivities
    from .uncertainty.validation import OutputMetrics as OutputMetrics
    from .uncertainty.validation import ValidationResult as ValidationResult
    from .uncertainty.validation import validate as validate

_aliases.install()  # the flat layout's module paths keep importing

# The rest of the public API is imported on first use: `import aeroid` (and with it
# the `aeroid` command, the pipeline and every worker it spawns) then pays only
# for the modules it touches, not for all of SciPy.
_LAZY = {
    "AircraftConstants": ".models.aircraft",
    "ChannelMap": ".io.channel_map",
    "ChannelSpec": ".io.channel_map",
    "apply_channel_map": ".io.channel_map",
    "flight_windows": ".io.channel_map",
    "load_mapped": ".io.channel_map",
    "FlightData": ".io.data",
    "load_flight_test": ".io.data",
    "AeroDatabase": ".uncertainty.database",
    "FlightCoefficients": ".uncertainty.database",
    "HeldOutCheck": ".uncertainty.database",
    "aerodynamic_database": ".uncertainty.database",
    "FlightLog": ".io._logtypes",
    "LogChannel": ".io._logtypes",
    "LogEvent": ".io._logtypes",
    "ChannelListing": ".io.logs",
    "list_channels": ".io.logs",
    "read_log": ".io.logs",
    "ChannelQuality": ".io.quality",
    "DataQualityReport": ".io.quality",
    "check_data_quality": ".io.quality",
    "coefficients_from_data": ".models.coefficients",
    "CompatibilityResult": ".estimation.compatibility",
    "check_compatibility": ".estimation.compatibility",
    "ExperimentDesign": ".uncertainty.design",
    "design_experiment": ".uncertainty.design",
    "FilterResult": ".estimation.filtering",
    "filter_states": ".estimation.filtering",
    "ChannelFrequencyResponse": ".frequency.response",
    "FrequencyResponseResult": ".frequency.response",
    "frequency_response": ".frequency.response",
    "FrequencyDomainResult": ".frequency.frequency_domain",
    "identify_frequency_domain": ".frequency.frequency_domain",
    "CompositeResponse": ".frequency.frequency_id",
    "ResponseChannel": ".frequency.frequency_id",
    "TransferFunctionFit": ".frequency.frequency_id",
    "composite_response": ".frequency.frequency_id",
    "fit_transfer_function": ".frequency.frequency_id",
    "BandwidthResult": ".frequency.handling_qualities",
    "EquivalentSystemFit": ".frequency.handling_qualities",
    "HandlingQualitiesLevel": ".frequency.handling_qualities",
    "bandwidth_level": ".frequency.handling_qualities",
    "short_period_level": ".frequency.handling_qualities",
    "Margins": ".frequency.handling_qualities",
    "bandwidth": ".frequency.handling_qualities",
    "equivalent_system": ".frequency.handling_qualities",
    "stability_margins": ".frequency.handling_qualities",
    "IdentificationResult": ".estimation.identification",
    "identify": ".estimation.identification",
    "EnsembleRun": ".uncertainty.inference",
    "InferenceResult": ".uncertainty.inference",
    "combine_ensembles": ".uncertainty.inference",
    "infer": ".uncertainty.inference",
    "infer_ensemble": ".uncertainty.inference",
    "simulate_rk4": ".models.jax_backend",
    "Chirp": ".uncertainty.maneuvers",
    "Doublet": ".uncertainty.maneuvers",
    "ManeuverFamily": ".uncertainty.maneuvers",
    "Multisine": ".uncertainty.maneuvers",
    "Multistep": ".uncertainty.maneuvers",
    "OrthogonalMultisine": ".uncertainty.orthogonal_multisines",
    "orthogonal_multisine": ".uncertainty.orthogonal_multisines",
    "BatchSimulation": ".models.model",
    "Model": ".models.model",
    "SimulationResult": ".models.model",
    "SimulatorModel": ".models.model",
    "HalfNormal": ".uncertainty.priors",
    "LogUniform": ".uncertainty.priors",
    "Normal": ".uncertainty.priors",
    "Prior": ".uncertainty.priors",
    "Uniform": ".uncertainty.priors",
    "PropagationBatch": ".uncertainty.propagation",
    "PropagationResult": ".uncertainty.propagation",
    "VectorPropagationResult": ".uncertainty.propagation",
    "combine_batches": ".uncertainty.propagation",
    "propagate": ".uncertainty.propagation",
    "propagate_batch": ".uncertainty.propagation",
    "OrthogonalFunctionResult": ".estimation.orthogonal_functions",
    "orthogonal_function_model": ".estimation.orthogonal_functions",
    "RecursiveResult": ".estimation.recursive_estimation",
    "recursive_least_squares": ".estimation.recursive_estimation",
    "RegressionResult": ".estimation.regression",
    "StepwiseResult": ".estimation.regression",
    "StepwiseStep": ".estimation.regression",
    "candidate_pool": ".estimation.regression",
    "equation_error": ".estimation.regression",
    "spline_terms": ".estimation.regression",
    "stepwise_regression": ".estimation.regression",
    "report": ".reports.reporting",
    "resample": ".io.resampling",
    "ChainState": ".uncertainty.sampler",
    "SamplerRun": ".uncertainty.sampler",
    "autocorrelation_time": ".uncertainty.sampler",
    "effective_sample_size": ".uncertainty.sampler",
    "ensemble_sampler": ".uncertainty.sampler",
    "split_r_hat": ".uncertainty.sampler",
    "ManeuverWindow": ".io.segmentation",
    "SegmentationResult": ".io.segmentation",
    "segment": ".io.segmentation",
    "SensitivityResult": ".uncertainty.sensitivity",
    "sensitivities": ".uncertainty.sensitivity",
    "differentiate": ".io.smoothing",
    "optimal_cutoff": ".io.smoothing",
    "smooth": ".io.smoothing",
    "OutputMetrics": ".uncertainty.validation",
    "PredictionResult": ".uncertainty.prediction",
    "ValidationResult": ".uncertainty.validation",
    "validate": ".uncertainty.validation",
}


if not TYPE_CHECKING:  # type checkers see the imports above, and no catch-all

    def __getattr__(name: str) -> object:
        from importlib import import_module

        module = _LAZY.get(name)
        if module is None and f"aeroid.{name}" in _aliases.MOVED:
            return import_module(f"aeroid.{name}")  # an old module path
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
