"""Pipeline definitions: which stages run, wired how.

A `Pipeline` is a list of per-flight `Step`s and campaign `Step`s. A step
names a stage (``aeroid.pipeline.stages``) and maps each of the stage's
input roles to an upstream step. Per-flight steps see one flight's upstream
results; campaign steps see, per role, the list of every flight's results.
Optional steps run only when the config lists them under ``stages:``; an
input whose upstream step does not run is left out.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .stages import STAGES

__all__ = ["Pipeline", "Step", "resolve_pipeline"]


@dataclass(frozen=True)
class Step:
    """One node of a pipeline.

    Parameters
    ----------
    name : str
        The step's name; its options live under ``stages.<name>`` in the config.
    stage : str, optional
        The stage it runs (default: `name`).
    inputs : mapping of str to str
        Input role of the stage -> name of the upstream step.
    optional : bool
        Run only when the config lists the step under ``stages``.
    """

    name: str
    stage: str | None = None
    inputs: Mapping[str, str] = field(default_factory=dict)
    optional: bool = False

    @property
    def stage_name(self) -> str:
        return self.stage or self.name


@dataclass(frozen=True)
class Pipeline:
    """Per-flight steps (in dependency order) and campaign steps over all flights."""

    name: str
    flight_steps: tuple[Step, ...]
    campaign_steps: tuple[Step, ...] = ()

    def __post_init__(self) -> None:
        seen: set[str] = set()
        for step in (*self.flight_steps, *self.campaign_steps):
            if step.stage_name not in STAGES:
                raise ConfigError(
                    f"pipeline {self.name!r}: step {step.name!r} runs unknown stage "
                    f"{step.stage_name!r}; stages: {sorted(STAGES)}"
                )
            for role, up in step.inputs.items():
                if up not in seen or up in {s.name for s in self.campaign_steps}:
                    raise ConfigError(
                        f"pipeline {self.name!r}: step {step.name!r} input {role!r} names "
                        f"{up!r}, which is not an earlier per-flight step"
                    )
            if step.name in seen:
                raise ConfigError(f"pipeline {self.name!r}: duplicate step {step.name!r}")
            if step in self.flight_steps:
                seen.add(step.name)
        names = [s.name for s in self.campaign_steps]
        if len(set(names)) != len(names):
            raise ConfigError(f"pipeline {self.name!r}: duplicate campaign steps")

    @property
    def steps(self) -> tuple[Step, ...]:
        return (*self.flight_steps, *self.campaign_steps)

    def enabled(self, configured: Mapping[str, Any]) -> list[Step]:
        """Steps that run for a config's ``stages`` mapping."""
        return [s for s in self.steps if not s.optional or s.name in configured]


def _candidate_dirs(base_dir: str | None) -> list[Path]:
    dirs: list[Path] = []
    if base_dir:
        here = Path(base_dir).resolve()
        dirs += [here, *here.parents]
    dirs.append(Path(__file__).resolve().parents[2])  # a source checkout of aeroid
    return dirs


def resolve_pipeline(spec: str, base_dir: str | None = None) -> tuple[Pipeline, dict[str, Any]]:
    """Find a pipeline by name (``pipelines/<name>.py``) or import path ``pkg.mod:attr``.

    Returns the pipeline and a reference (module and search directory) that
    worker processes use to import the same definition.
    """
    if ":" in spec:
        module, _, attr = spec.partition(":")
        search = str(Path(base_dir).resolve()) if base_dir else None
    else:
        module, attr, search = f"pipelines.{spec}", "pipeline", None
        for d in _candidate_dirs(base_dir):
            if (d / "pipelines" / f"{spec}.py").is_file():
                search = str(d)
                break
    ref = {"module": module, "attr": attr, "path": search}
    return load_pipeline(ref, spec=spec), ref


def load_pipeline(ref: Mapping[str, Any], *, spec: str | None = None) -> Pipeline:
    """Import a pipeline from a reference made by `resolve_pipeline`."""
    path = ref.get("path")
    if path and path not in sys.path:
        sys.path.insert(0, path)
    what = spec or f"{ref['module']}:{ref['attr']}"
    try:
        mod = importlib.import_module(ref["module"])
    except ImportError as exc:
        raise ConfigError(f"pipeline {what!r}: cannot import {ref['module']!r} ({exc})") from None
    obj = getattr(mod, ref["attr"], None)
    if not isinstance(obj, Pipeline):
        raise ConfigError(f"pipeline {what!r}: {ref['module']}.{ref['attr']} is not a Pipeline")
    return obj
