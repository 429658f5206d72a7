"""What a campaign config describes in its own terms where a library function takes
objects: a prior (`PriorSpec`), a built-in manoeuvre family (`ManeuverSpec`)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, model_validator

from ...errors import AeroidError, PipelineError
from ..plans.config import Options

__all__ = ["ManeuverSpec", "PriorSpec"]


def _simulate_keys(value: Any) -> Any:
    """`simulate_options` whose keys are the library's: checked before any flight loads
    (their values need the model: `check_campaign` checks them)."""
    from ...models.model import SIMULATE_OPTION_KEYS

    unknown = sorted(set(value or {}) - set(SIMULATE_OPTION_KEYS))
    if unknown:
        raise ValueError(f"unknown keys {unknown}; valid keys are {list(SIMULATE_OPTION_KEYS)}")
    return value


# types narrower than the library's `str`: the values it takes (tests/test_engine_parts.py
# pins them to the library's lists), so that a typo is refused before any flight runs
_SIMULATE: Any = (Annotated[dict[str, Any] | None, AfterValidator(_simulate_keys)], Field(None))
_ERROR_BARS: Any = (Literal["colored", "white"] | None, Field(None))
_GRADIENT: Any = (Literal["auto", "fd", "jax"] | None, Field(None))


class PriorSpec(Options):
    """One prior: exactly one of normal [mu, sigma], uniform [lo, hi], log_uniform [lo, hi],
    half_normal sigma."""

    normal: tuple[float, float] | None = None
    uniform: tuple[float, float] | None = None
    log_uniform: tuple[float, float] | None = None
    half_normal: float | None = None

    @model_validator(mode="after")
    def _builds(self) -> PriorSpec:
        # a sigma of -1 or lo above hi is a config error, found before any run
        try:
            self.build("this parameter")
        except AeroidError as exc:
            raise ValueError(str(exc)) from None
        return self

    def build(self, name: str) -> Any:
        from ...uncertainty.priors import HalfNormal, LogUniform, Normal, Uniform

        given = self.model_dump(exclude_none=True)
        if len(given) != 1:
            raise PipelineError(
                f"prior of {name!r}: give exactly one of normal, uniform, log_uniform, half_normal"
            )
        kind, args = next(iter(given.items()))
        cls: Any = {
            "normal": Normal,
            "uniform": Uniform,
            "log_uniform": LogUniform,
            "half_normal": HalfNormal,
        }[kind]
        return cls(*args) if isinstance(args, (tuple, list)) else cls(args)


class ManeuverSpec(Options):
    """A built-in manoeuvre family: ``type`` and its constructor arguments."""

    type: Literal["multisine", "doublet", "multistep", "chirp"]
    control: str
    options: dict[str, Any] = Field(default_factory=dict)

    @model_validator(mode="after")
    def _builds(self) -> ManeuverSpec:
        # a missing or unknown constructor argument is a config error, found before any run
        try:
            self.build()
        except (TypeError, AeroidError) as exc:
            raise ValueError(f"options do not make a {self.type}: {exc}") from None
        return self

    def build(self) -> Any:
        from ...uncertainty.maneuvers import Chirp, Doublet, Multisine, Multistep

        families: dict[str, Any] = {
            "multisine": Multisine,
            "doublet": Doublet,
            "multistep": Multistep,
            "chirp": Chirp,
        }
        cls = families[self.type]
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in self.options.items()}
        return cls(self.control, **kw)
