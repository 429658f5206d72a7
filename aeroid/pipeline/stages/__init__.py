"""Pipeline stages: the contract and the registry.

A stage declares its options model (built from the library function's
signature), the record type it produces, whether it needs the vehicle model
and whether it is stochastic, and a ``run(ctx)`` function. Adding a stage is
one `register_stage` call; pipelines (``pipelines/``) wire stages together.
This package's modules are the stages seam: the built-in stages in
`load_stage`, `library_stages` (one per library function), `analysis_stages`,
`database_stage` and `campaign_report`, which `builtin` imports (and they
register here) when `aeroid.pipeline` is imported; `work`, a task's work in
its stage in one call; and `run_outputs`, what a run leaves once its tasks are
done (the store's index, the database's files, the report) in one call. The contract itself (this module) is the vocabulary
every seam shares: planning reads the stages' options, the run looks them up.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ...errors import PipelineError
from .._code import resolve
from .._options import Options

__all__ = [
    "FIGURE_IMPORTS",
    "STAGES",
    "STAGE_ALIASES",
    "CampaignReport",
    "FlightReport",
    "Stage",
    "StageContext",
    "register_stage",
    "resolve_callable",
]


# -- records produced by the pipeline itself -------------------------------------


@dataclass(frozen=True, eq=False)
class FlightReport:
    """The Markdown engineering report of one flight."""

    title: str
    markdown: str

    def summary(self) -> str:
        return self.markdown


@dataclass(frozen=True, eq=False)
class CampaignReport:
    """The campaign report: a per-flight table, failures, each flight's report and figures.

    `figures` holds PNG images (bytes as ``uint8`` arrays) titled by
    `figure_titles`: the trend of every estimate across flights and the
    detailed figures of the first flight that was identified.
    """

    title: str
    markdown: str
    flights: tuple[str, ...]
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    failures: Mapping[str, str] = field(default_factory=dict)
    figure_titles: tuple[str, ...] = ()
    figures: tuple[np.ndarray, ...] = ()

    def __post_init__(self) -> None:
        pngs = []
        for png in self.figures:
            arr = np.frombuffer(png, dtype=np.uint8) if isinstance(png, bytes) else png
            arr = np.array(arr, dtype=np.uint8, copy=True)
            arr.setflags(write=False)
            pngs.append(arr)
        if len(pngs) != len(self.figure_titles):
            raise PipelineError("CampaignReport: one title per figure expected")
        object.__setattr__(self, "figures", tuple(pngs))

    def figure_bytes(self) -> dict[str, bytes]:
        """The PNG images by title."""
        return {t: f.tobytes() for t, f in zip(self.figure_titles, self.figures, strict=True)}

    def summary(self) -> str:
        return self.markdown


# -- the stage contract -------------------------------------------------------------


@dataclass
class StageContext:
    """What a stage's ``run`` receives on the worker."""

    options: Any
    inputs: dict[str, Any]
    model: Any = None
    seed: np.random.SeedSequence | None = None
    flight: str | None = None
    source: Mapping[str, Any] | None = None
    failures: Mapping[str, str] = field(default_factory=dict)
    flights: tuple[str, ...] = ()
    # role -> {flight index: brief} handed over by the flights' tasks (see `Stage.brief`)
    briefs: Mapping[str, Mapping[int, Any]] = field(default_factory=dict)
    summarize: Callable[[str, Any], Any] | None = None
    # the config's folder, where the options name code in it (`Task.code_dir`)
    code_dir: str | None = None

    def brief(self, role: str, index: int) -> Any:
        """The brief of flight `index`'s `role` input (see `Stage.brief`): the one its task
        handed over, else made from the record (read on access); None where the flight
        failed or the role is not an input."""
        given = self.briefs.get(role)
        if given is not None and index in given:
            return given[index]
        if role not in self.inputs or self.summarize is None:
            return None
        record = self.inputs[role][index]
        return None if record is None else self.summarize(role, record)

    def seed_sequence(self, *extra: int) -> np.random.SeedSequence:
        """This task's `SeedSequence`, or its child with `extra` appended to the spawn key."""
        if self.seed is None:
            raise PipelineError("this stage has no seed specification")
        return np.random.SeedSequence(self.seed.entropy, spawn_key=(*self.seed.spawn_key, *extra))

    def seed_int(self, *extra: int) -> int:
        """A 64-bit integer seed from this task's `SeedSequence` (child `extra` if given)."""
        if self.seed is None:
            raise PipelineError("this stage has no seed specification")
        ss = self.seed
        if extra:
            ss = np.random.SeedSequence(ss.entropy, spawn_key=(*ss.spawn_key, *extra))
        return int(ss.generate_state(1, dtype=np.uint64)[0])


@dataclass(frozen=True)
class Stage:
    """A pipeline stage.

    Attributes
    ----------
    name : str
    version : str
        Bump when the wrapper's behaviour changes; it enters every key.
    options : type of Options
        The stage's options model (unknown keys are config errors).
    record_type : str
        Name of the record type produced (a label that enters the key).
    run : callable
        ``run(ctx: StageContext) -> record``.
    uses_model : bool
        The model fingerprint enters the key and the model is passed in.
    seeded : bool
        The task gets ``SeedSequence(seed, spawn_key=(flight,))``.
    library : str or None
        The library function wrapped, as ``module:function`` (imported when
        the stage runs); `register_stage` takes it from the options model's
        ``library`` when not given, so every built-in stage names its function.
    per_flight : bool
        False for campaign-level stages whose inputs are lists over flights.
    parts : callable, optional
        ``parts(options, roles) -> n`` (`roles`: the task's input roles):
        the task splits into `n` independent parts
        (MCMC ensembles, Monte Carlo batches) that run in parallel, each with
        its own random stream; ``run_part(ctx, i)`` computes part `i` and
        ``combine(ctx, parts)`` the stored record. Results equal the unsplit
        computation whatever runs which part.
    part_flights : callable, optional
        ``part_flights(options, roles, i)``: for a campaign-level split task,
        the flights (indices) part `i` reads; it then waits only for those
        flights. None (or the callable returning None): every flight.
    stored_as : str or None
        The name a renamed stage had: it stays in the keys of the stage's
        results (`key_name`), so results stored before the rename are found.
    brief : callable, optional
        ``brief(role, record) -> value: for a campaign-level stage, the small
        part of one flight's `role` input it needs (a few numbers and strings;
        picklable). The flight's task makes it as it commits the record, while
        the record is in memory, and hands it over with its status, so the
        campaign task reads no entry for it; ``ctx.brief(role, i)`` returns it,
        or makes it from the stored record when no task handed it over (a
        cached flight, a rerun). Either way it is the same value.
    imports : tuple of str
        Modules its tasks import as they run beyond `library` (the figures' plotting
        modules): a run imports them once before it forks its worker processes,
        which then share them instead of each importing them.
    names_flight : bool
        The record shows the flight's name and file (a report): both enter the key, so
        a renamed flight file is shown under its new name, and the task gets the
        flight's source as ``ctx.source``.
    files : callable, optional
        ``files(record) -> {name: bytes}``: files the run writes beside its report from
        a campaign-level result (the database's plots). The worker that computed the
        result makes them while the record is in memory and hands them over with its
        status (they are not stored), so the run's own process, which writes them after
        the last task, does not draw them then; a run that finds the result stored
        makes them itself.
    """

    name: str
    version: str
    options: type[Options]
    record_type: str
    run: Callable[[StageContext], Any]
    uses_model: bool = True
    seeded: bool = False
    library: str | None = None
    per_flight: bool = True
    parts: Callable[[Any, frozenset[str]], int] | None = None
    run_part: Callable[[StageContext, int], Any] | None = None
    combine: Callable[[StageContext, list[Any]], Any] | None = None
    part_flights: Callable[[Any, frozenset[str], int], tuple[int, ...] | None] | None = None
    brief: Callable[[str, Any], Any] | None = None
    stored_as: str | None = None
    imports: tuple[str, ...] = ()
    files: Callable[[Any], Mapping[str, bytes]] | None = None
    names_flight: bool = False

    @property
    def key_name(self) -> str:
        """The stage's name in its results' keys: `stored_as` where it was renamed."""
        return self.stored_as or self.name


#: Old stage name -> the name that says what the stage does. An old name still finds
#: its stage (a pipeline naming it gets a DeprecationWarning), and the stage's results
#: keep their keys and their folder in the store (`Stage.key_name`).
STAGE_ALIASES: dict[str, str] = {
    "frequency": "frequency_response",
    "frequency_id": "composite_response",
    "frequency_identify": "frequency_domain_identify",
}


class _Registry(dict[str, Stage]):
    """Stages by name; an old name in `STAGE_ALIASES` finds the renamed stage (tasks
    name a stage by `Stage.key_name`, so the engine itself looks old names up)."""

    def _current(self, name: object) -> object:
        new = STAGE_ALIASES.get(name) if isinstance(name, str) else None
        return name if new is None or dict.__contains__(self, name) else new

    def __missing__(self, name: str) -> Stage:
        current = self._current(name)
        if current == name:
            raise KeyError(name)
        return self[str(current)]

    def __contains__(self, name: object) -> bool:
        return dict.__contains__(self, self._current(name))

    def get(self, name: str, default: Any = None) -> Any:
        return self[name] if name in self else default


STAGES: dict[str, Stage] = _Registry()

#: What a stage that draws figures imports as it draws them (its `Stage.imports`).
FIGURE_IMPORTS = (
    "aeroid.reports.plotting",
    "matplotlib.backends.backend_agg",
    "PIL.Image",
    "PIL.PngImagePlugin",
)


def register_stage(stage: Stage) -> Stage:
    """Make a stage available to pipelines by name (replacing one of the same name).

    A stage given no ``library`` takes its options model's ``library``
    (``module:function``), when the model names one."""
    if stage.library is None:
        library = getattr(stage.options, "library", None)
        if isinstance(library, str):
            stage = replace(stage, library=library)
    STAGES[stage.name] = stage
    return stage


def resolve_callable(spec: str, *, what: str, base_dir: str | None = None) -> Any:
    """Import ``package.module:attribute`` (dotted attributes allowed): the module's file
    in `base_dir` (the config's folder) when there is one, else the installed module."""
    return resolve(spec, base_dir, what=what, error=PipelineError)
