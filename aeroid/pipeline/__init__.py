"""The campaign pipeline: content-keyed stages, a Zarr result store, Dask execution.

Use it from Python the way the ``aeroid`` command does::

    from aeroid import pipeline

    summary = pipeline.run("configs/demo.yaml")          # compute what is missing
    store = pipeline.open_store(".aeroid-store")
    for entry in store.entries("identify"):
        result = store.load(entry.key, entry.stage)      # an IdentificationResult

Numerical modules never import this package.
"""

from .stages import builtin as _builtin_stages  # registers the built-in stages

# isort: split
from .definition import Pipeline, Step, resolve_pipeline
from .keys import model_fingerprint, task_key
from .plans.config import CampaignConfig, load_config
from .plans.planning import Plan, Task, plan, resolve_model
from .running.execution import TaskStatus, execute_task
from .running.runner import RunSummary, run
from .stages import STAGES, CampaignReport, FlightReport, Stage, StageContext, register_stage
from .storage.codec import exported_records, register_record
from .storage.store import Claim, Entry, ResultStore, StoreLocation, open_store

__all__ = [
    "STAGES",
    "CampaignConfig",
    "CampaignReport",
    "Claim",
    "Entry",
    "FlightReport",
    "Pipeline",
    "Plan",
    "ResultStore",
    "RunSummary",
    "Stage",
    "StageContext",
    "Step",
    "StoreLocation",
    "Task",
    "TaskStatus",
    "execute_task",
    "load_config",
    "model_fingerprint",
    "open_store",
    "plan",
    "register_record",
    "register_stage",
    "resolve_model",
    "resolve_pipeline",
    "run",
    "task_key",
]

# the records exported above are stored under their bare names, as aeroid's own are
exported_records(__name__, __all__)
del _builtin_stages
