"""What a campaign config describes in its own terms where a library function takes
objects: a prior (`PriorSpec`), a built-in manoeuvre family (`ManeuverSpec`)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, model_validator

from ...errors import AeroidError, PipelineError
from ..plans.config import Options

__all__ = ["ManeuverSpec", "PriorSpec"]


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
