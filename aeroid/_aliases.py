"""The module paths of the flat layout (before issue 50), kept importable.

``import aeroid.identification``, ``from aeroid.aircraft import lateral``, pickles
and stored records that name ``aeroid.<module>:<Class>`` load the module that
now lives in a subpackage, as the same object: one finder on `sys.meta_path`,
no module per old name. Nothing is imported until an old name is asked for.
The codec and the model fingerprint write these old names (`legacy_name`), so
stored bytes and task keys stay as they were.

Written by the move scripts (house_move.py, then k50_move.py for the engine's
seams): edit their tables, not this one.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Sequence
from importlib.machinery import ModuleSpec
from types import ModuleType
from typing import TYPE_CHECKING, cast

if TYPE_CHECKING:
    from importlib.abc import Loader

__all__: list[str] = []

# old dotted name -> the module it is now
MOVED: dict[str, str] = {
    "aeroid._aircraft_linear": "aeroid.models._aircraft_linear",
    "aeroid._aircraft_nonlinear": "aeroid.models._aircraft_nonlinear",
    "aeroid._aircraft_parts": "aeroid.models._aircraft_parts",
    "aeroid._aircraft_six_dof": "aeroid.models._aircraft_six_dof",
    "aeroid._aircraft_trim": "aeroid.models._aircraft_trim",
    "aeroid._autopilot_logs": "aeroid.io._autopilot_logs",
    "aeroid._batch_function": "aeroid.models._batch_function",
    "aeroid._compat_arguments": "aeroid.estimation._compat_arguments",
    "aeroid._compat_input_noise": "aeroid.estimation._compat_input_noise",
    "aeroid._compat_model": "aeroid.estimation._compat_model",
    "aeroid._compiled": "aeroid.models.compiled",
    "aeroid._criteria": "aeroid.frequency._criteria",
    "aeroid._cross_spectra": "aeroid.frequency._cross_spectra",
    "aeroid._database_export": "aeroid.uncertainty.database_export",
    "aeroid._ekf_compiled": "aeroid.estimation._ekf_compiled",
    "aeroid._excitation": "aeroid.estimation._excitation",
    "aeroid._filter_error": "aeroid.estimation._filter_error",
    "aeroid._filter_problem": "aeroid.estimation._filter_problem",
    "aeroid._filter_steady": "aeroid.estimation._filter_steady",
    "aeroid._fitted_parameters": "aeroid.models._fitted_parameters",
    "aeroid._flight_csv": "aeroid.io._flight_csv",
    "aeroid._frequency_domain_fits": "aeroid.frequency._frequency_domain_fits",
    "aeroid._html": "aeroid.reports.html",
    "aeroid._identifiability": "aeroid.estimation.identifiability",
    "aeroid._identification_record": "aeroid.estimation._identification_record",
    "aeroid._identification_start": "aeroid.estimation._identification_start",
    "aeroid._inference_record": "aeroid.uncertainty._inference_record",
    "aeroid._integrate": "aeroid.models.integration",
    "aeroid._jax": "aeroid.models.jax_compiled",
    "aeroid._jax_rk4": "aeroid.models._jax_rk4",
    "aeroid._jax_translation": "aeroid.models._jax_translation",
    "aeroid._kalman_linear": "aeroid.estimation._kalman_linear",
    "aeroid._kalman_nonlinear": "aeroid.estimation._kalman_nonlinear",
    "aeroid._least_squares": "aeroid.estimation.least_squares",
    "aeroid._loes_fit": "aeroid.frequency._loes_fit",
    "aeroid._logtypes": "aeroid.io._logtypes",
    "aeroid._mat_scan": "aeroid.io._mat_scan",
    "aeroid._model_base": "aeroid.models._model_base",
    "aeroid._model_response": "aeroid.frequency._model_response",
    "aeroid._noise_model": "aeroid.estimation._noise_model",
    "aeroid._output_error": "aeroid.estimation._output_error",
    "aeroid._posterior": "aeroid.uncertainty._posterior",
    "aeroid._prediction": "aeroid.uncertainty.prediction",
    "aeroid._rational_fit": "aeroid.frequency._rational_fit",
    "aeroid._regression_fits": "aeroid.estimation._regression_fits",
    "aeroid._regression_record": "aeroid.estimation._regression_record",
    "aeroid._regressors": "aeroid.estimation._regressors",
    "aeroid._regrid": "aeroid.io._regrid",
    "aeroid._response_estimates": "aeroid.frequency._response_estimates",
    "aeroid._response_function": "aeroid.frequency._response_function",
    "aeroid._response_records": "aeroid.frequency._response_records",
    "aeroid._rk4_grid": "aeroid.models._rk4_grid",
    "aeroid._shooting": "aeroid.models.shooting",
    "aeroid._simulation_checks": "aeroid.models._simulation_checks",
    "aeroid._simulation_results": "aeroid.models._simulation_results",
    "aeroid._state_biases": "aeroid.estimation._state_biases",
    "aeroid._state_space": "aeroid.models.state_space",
    "aeroid._table_files": "aeroid.io._table_files",
    "aeroid._transfer": "aeroid.frequency._transfer",
    "aeroid.aircraft": "aeroid.models.aircraft",
    "aeroid.catalog": "aeroid.models.catalog",
    "aeroid.channel_map": "aeroid.io.channel_map",
    "aeroid.coefficients": "aeroid.models.coefficients",
    "aeroid.compatibility": "aeroid.estimation.compatibility",
    "aeroid.data": "aeroid.io.data",
    "aeroid.database": "aeroid.uncertainty.database",
    "aeroid.design": "aeroid.uncertainty.design",
    "aeroid.filtering": "aeroid.estimation.filtering",
    "aeroid.frequency_domain": "aeroid.frequency.frequency_domain",
    "aeroid.frequency_id": "aeroid.frequency.frequency_id",
    "aeroid.handling_qualities": "aeroid.frequency.handling_qualities",
    "aeroid.identification": "aeroid.estimation.identification",
    "aeroid.inference": "aeroid.uncertainty.inference",
    "aeroid.jax_backend": "aeroid.models.jax_backend",
    "aeroid.logs": "aeroid.io.logs",
    "aeroid.maneuvers": "aeroid.uncertainty.maneuvers",
    "aeroid.model": "aeroid.models.model",
    "aeroid.pipeline._backend": "aeroid.pipeline.storage._backend",
    "aeroid.pipeline._cache": "aeroid.pipeline.storage._cache",
    "aeroid.pipeline._campaign_tables": "aeroid.pipeline.stages._campaign_tables",
    "aeroid.pipeline._check_common": "aeroid.pipeline.plans._check_common",
    "aeroid.pipeline._database_report": "aeroid.pipeline.stages._database_report",
    "aeroid.pipeline._file_checks": "aeroid.pipeline.plans._file_checks",
    "aeroid.pipeline._flights": "aeroid.pipeline.plans._flights",
    "aeroid.pipeline._objectstore": "aeroid.pipeline.storage._objectstore",
    "aeroid.pipeline._paths": "aeroid.pipeline.plans._paths",
    "aeroid.pipeline._process": "aeroid.pipeline.running._process",
    "aeroid.pipeline._rename": "aeroid.pipeline.storage._rename",
    "aeroid.pipeline._store_paths": "aeroid.pipeline.storage._store_paths",
    "aeroid.pipeline._yaml": "aeroid.pipeline.plans._yaml",
    "aeroid.pipeline._zipentry": "aeroid.pipeline.storage._zipentry",
    "aeroid.pipeline.analysis_stages": "aeroid.pipeline.stages.analysis_stages",
    "aeroid.pipeline.builtin_stages": "aeroid.pipeline.stages.builtin",
    "aeroid.pipeline.campaign_report": "aeroid.pipeline.stages.campaign_report",
    "aeroid.pipeline.checks": "aeroid.pipeline.plans.checks",
    "aeroid.pipeline.claims": "aeroid.pipeline.storage.claims",
    "aeroid.pipeline.codec": "aeroid.pipeline.storage.codec",
    "aeroid.pipeline.commits": "aeroid.pipeline.storage.commits",
    "aeroid.pipeline.config": "aeroid.pipeline.plans.config",
    "aeroid.pipeline.database_stage": "aeroid.pipeline.stages.database_stage",
    "aeroid.pipeline.execution": "aeroid.pipeline.running.execution",
    "aeroid.pipeline.executors": "aeroid.pipeline.running.executors",
    "aeroid.pipeline.flight_specs": "aeroid.pipeline.plans.flight_specs",
    "aeroid.pipeline.flight_status": "aeroid.pipeline.stages.flight_status",
    "aeroid.pipeline.graph": "aeroid.pipeline.running.graph",
    "aeroid.pipeline.ledger": "aeroid.pipeline.running.ledger",
    "aeroid.pipeline.library_stages": "aeroid.pipeline.stages.library_stages",
    "aeroid.pipeline.load_stage": "aeroid.pipeline.stages.load_stage",
    "aeroid.pipeline.metrics": "aeroid.pipeline.stages.metrics",
    "aeroid.pipeline.plan_cache": "aeroid.pipeline.plans.plan_cache",
    "aeroid.pipeline.plan_checks": "aeroid.pipeline.plans.plan_checks",
    "aeroid.pipeline.planning": "aeroid.pipeline.plans.planning",
    "aeroid.pipeline.rerun": "aeroid.pipeline.running.rerun",
    "aeroid.pipeline.runner": "aeroid.pipeline.running.runner",
    "aeroid.pipeline.signature_options": "aeroid.pipeline.stages.signature_options",
    "aeroid.pipeline.store": "aeroid.pipeline.storage.store",
    "aeroid.pipeline.streaming": "aeroid.pipeline.running.streaming",
    "aeroid.pipeline.synthetic": "aeroid.pipeline.plans.synthetic",
    "aeroid.pipeline.verified": "aeroid.pipeline.storage.verified",
    "aeroid.pipeline.work": "aeroid.pipeline.stages.work",
    "aeroid.plotting": "aeroid.reports.plotting",
    "aeroid.priors": "aeroid.uncertainty.priors",
    "aeroid.propagation": "aeroid.uncertainty.propagation",
    "aeroid.quality": "aeroid.io.quality",
    "aeroid.regression": "aeroid.estimation.regression",
    "aeroid.reporting": "aeroid.reports.reporting",
    "aeroid.resampling": "aeroid.io.resampling",
    "aeroid.sampler": "aeroid.uncertainty.sampler",
    "aeroid.segmentation": "aeroid.io.segmentation",
    "aeroid.sensitivity": "aeroid.uncertainty.sensitivity",
    "aeroid.smoothing": "aeroid.io.smoothing",
    "aeroid.validation": "aeroid.uncertainty.validation",
}
_LEGACY = {new: old for old, new in MOVED.items()}


def legacy_name(module: str) -> str:
    """The flat-layout name of `module` (itself when it did not move)."""
    return _LEGACY.get(module, module)


class _Alias:
    """Loads an old name as the module it moved to (the same object)."""

    def __init__(self, target: str) -> None:
        self.target = target
        self.spec: ModuleSpec | None = None

    def create_module(self, spec: ModuleSpec) -> ModuleType:
        module = importlib.import_module(self.target)
        self.spec = module.__spec__
        return module

    def exec_module(self, module: ModuleType) -> None:
        # the import system set the alias's spec on the module: give it its own back
        module.__spec__ = self.spec


class _OldPaths:
    """The finder on `sys.meta_path` for the names in `MOVED`."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None = None, target: ModuleType | None = None
    ) -> ModuleSpec | None:
        moved = MOVED.get(fullname)
        if moved is None:
            return None
        return ModuleSpec(fullname, cast("Loader", _Alias(moved)))


_FINDER = _OldPaths()


def install() -> None:
    """Put the finder on `sys.meta_path` (once)."""
    if _FINDER not in sys.meta_path:
        sys.meta_path.append(_FINDER)
