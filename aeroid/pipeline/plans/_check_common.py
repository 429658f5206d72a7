"""What the pre-flight checks share: the model's names, hints, the list of problems."""

from __future__ import annotations

import difflib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from ...errors import ConfigError

_MAX_PROBLEMS = 50  # lines in one error; a glob of a thousand bad files says so once
_HEADER_BYTES = 64 * 1024  # a CSV header (with its comment lines) is shorter than this
_CSV_SUFFIXES = (".csv", ".txt", ".dat")
_PARQUET_SUFFIXES = (".parquet", ".pq")
# what `aeroid.load_flight_test` tries when no time column is named
_TIME_CANDIDATES = ("time", "t", "Time", "TIME", "time_s", "Time (s)", "t_s")
_MATLAB_NUMERIC = frozenset(
    {
        "double",
        "single",
        "logical",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
    }
)
# stages whose library function reads the flight's controls and outputs
_READS_DATA = frozenset(
    {
        "identify",
        "filter",
        "validate",
        "infer",
        "frequency_response",
        "sensitivities",
        "frequency_domain_identify",
    }
)

# (stage, option) -> which of the model's names the option's entries are
# ("parameter", "state", "output", "control"; "output or state" for either)
_NAMED: dict[tuple[str, str], str] = {
    ("identify", "parameters"): "parameter",
    ("identify", "bounds"): "parameter",
    ("identify", "x0"): "state",
    ("identify", "estimate_x0"): "state",
    ("identify", "estimate_bias"): "output or state",
    ("identify", "outputs"): "output",
    ("identify", "weights"): "output",
    ("identify", "process_noise"): "state",
    ("identify", "measurement_noise"): "output",
    ("identify", "estimate_process_noise"): "state",
    ("filter", "process_noise"): "state",
    ("filter", "measurement_noise"): "output",
    ("validate", "outputs"): "output",
    ("infer", "parameters"): "parameter",
    ("infer", "priors"): "parameter",  # the old name of `parameters`
    ("infer", "noise"): "output",
    ("infer", "outputs"): "output",
    ("design", "parameters"): "parameter",
    ("design", "noise"): "output",
    ("frequency_response", "inputs"): "control",
    ("frequency_response", "outputs"): "output",
    ("sensitivities", "parameters"): "parameter",
    ("sensitivities", "noise"): "output",
    ("sensitivities", "outputs"): "output",
    ("frequency_domain_identify", "parameters"): "parameter",
    ("frequency_domain_identify", "outputs"): "output",
    ("frequency_domain_identify", "noise"): "output",
}


@dataclass(frozen=True)
class _ModelNames:
    name: str
    parameter: tuple[str, ...]
    state: tuple[str, ...] | None  # None: an external simulator has no named states
    control: tuple[str, ...]
    output: tuple[str, ...]
    nominal: Mapping[str, float]

    @classmethod
    def of(cls, model: Any) -> _ModelNames:
        params = getattr(model, "parameters", None) or {}
        states = getattr(model, "states", None)
        outputs = getattr(model, "output_names", None) or getattr(model, "outputs", None) or ()
        return cls(
            name=str(getattr(model, "name", "model")),
            parameter=tuple(str(p) for p in params),
            state=None if states is None else tuple(str(s) for s in states),
            control=tuple(str(c) for c in getattr(model, "controls", ()) or ()),
            output=tuple(str(o) for o in outputs),
            nominal={str(k): v for k, v in dict(params).items()},
        )

    def names(self, kind: str) -> tuple[str, ...] | None:
        if kind == "output or state":
            return None if self.state is None else (*self.output, *self.state)
        found: tuple[str, ...] | None = getattr(self, kind)
        return found


def _hint(name: str, choices: Iterable[str], what: str = "") -> str:
    """'; did you mean X?' for a close match, else the choices (when few enough)."""
    pool = sorted({str(c) for c in choices})
    close = difflib.get_close_matches(name, pool, n=2, cutoff=0.6)
    if close:
        return "; did you mean " + " or ".join(repr(c) for c in close) + "?"
    if pool and len(pool) <= 12:
        return f"; {what or 'expected one of'}: {', '.join(pool)}"
    return ""


class _Problems:
    """The faults found so far, each a line ``source: key.path: fault``."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.lines: list[str] = []

    def add(self, where: str, fault: str) -> None:
        line = f"{self.source}: {where}: {fault}"
        if line not in self.lines:
            self.lines.append(line)

    def add_lines(self, text: str) -> None:
        for line in text.splitlines():
            if line and line not in self.lines:
                self.lines.append(line)

    def raise_any(self) -> None:
        if not self.lines:
            return
        lines = self.lines[:_MAX_PROBLEMS]
        if len(self.lines) > _MAX_PROBLEMS:
            lines.append(f"{self.source}: ... and {len(self.lines) - _MAX_PROBLEMS} more problems")
        raise ConfigError("\n".join(lines))


# -- the entry points -------------------------------------------------------------------------


def _generators() -> dict[str, Any]:
    from . import synthetic

    registry = getattr(synthetic, "GENERATORS", None)
    if isinstance(registry, Mapping):
        return dict(registry)
    return {"short_period_campaign": synthetic.fly}
