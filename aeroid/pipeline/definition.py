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
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from ._code import load_file, module_file, user_module_name
from .stages import STAGE_ALIASES, STAGES

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
            if step.stage_name in STAGE_ALIASES:
                warnings.warn(
                    f"pipeline {self.name!r}: step {step.name!r} runs stage "
                    f"{step.stage_name!r}, now called {STAGE_ALIASES[step.stage_name]!r}; "
                    "the old name goes in a later release",
                    DeprecationWarning,
                    stacklevel=3,
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


def _pipeline_file(spec: str, base_dir: str | None) -> Path | None:
    """``<name>.py`` in the config's folder or its ``pipelines/``, else in aeroid's own
    ``pipelines/``; never in any other folder."""
    if not spec.isidentifier():
        return None
    dirs = [Path(base_dir) / "pipelines", Path(base_dir)] if base_dir else []
    dirs.append(_PACKAGE_PIPELINES)
    for d in dirs:
        if (d / f"{spec}.py").is_file():
            return (d / f"{spec}.py").resolve()
    return None


# the standard pipelines, installed beside the `aeroid` package
_PACKAGE_PIPELINES = Path(__file__).resolve().parents[2] / "pipelines"


def resolve_pipeline(
    spec: str, base_dir: str | None = None, *, allow_imports: bool = False
) -> tuple[Pipeline, dict[str, Any]]:
    """Find a pipeline by name (``pipelines/<name>.py``) or as ``module:attribute``.

    A name is looked up in the config's folder (`base_dir`) and its
    ``pipelines/``, then in aeroid's own ``pipelines/``; ``module:attribute``
    in the config's folder, else among installed modules, which only
    `allow_imports` permits. Files are run by path: no folder is added to
    `sys.path`. Returns the pipeline and a reference that worker processes use
    to load the same definition.
    """
    ref: dict[str, Any]
    if ":" in spec:
        module, _, attr = spec.partition(":")
        path = module_file(module, base_dir)
        if path is None and not allow_imports:
            raise ConfigError(
                f"pipeline {spec!r}: no {module.replace('.', '/')}.py beside the config; "
                "importing an installed module runs its code: allow it with "
                "`allow_imports: true` in the config or `--allow-imports`"
            )
        ref = {"module": module, "attr": attr}
        if path is not None:
            ref["file"] = str(path)
    else:
        path = _pipeline_file(spec, base_dir)
        if path is None:
            raise ConfigError(
                f"pipeline {spec!r}: no pipelines/{spec}.py in {base_dir or 'the config folder'} "
                f"or in {_PACKAGE_PIPELINES}"
            )
        ref = {"module": f"pipelines.{spec}", "attr": "pipeline", "file": str(path)}
    return load_pipeline(ref, spec=spec), ref


def load_pipeline(ref: Mapping[str, Any], *, spec: str | None = None) -> Pipeline:
    """Load a pipeline from a reference made by `resolve_pipeline` (by file path when it
    names a file; references stored by earlier versions name a search folder)."""
    what = spec or f"{ref['module']}:{ref['attr']}"
    file = ref.get("file")
    if file is None and ref.get("path"):  # stored by an earlier version
        file = module_file(ref["module"], ref["path"])
    try:
        if file is not None:
            mod = load_file(Path(file), user_module_name(ref["module"]), ref["module"])
        else:
            mod = importlib.import_module(ref["module"])
    except (ImportError, OSError) as exc:
        raise ConfigError(f"pipeline {what!r}: cannot load {ref['module']!r} ({exc})") from None
    obj = getattr(mod, ref["attr"], None)
    if not isinstance(obj, Pipeline):
        raise ConfigError(f"pipeline {what!r}: {ref['module']}.{ref['attr']} is not a Pipeline")
    return obj
