"""A campaign's task: one node of the task graph, as the plan makes it and as a
store keeps it beside its result (`Task.to_json`, read back by `Task.from_json`)."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..keys import canonical_json

__all__ = ["Task"]


@dataclass(frozen=True)
class Task:
    """One node of the task graph (plain data, so it travels to workers)."""

    key: str
    step: str
    stage: str
    flight: str | None
    options: dict[str, Any]
    upstream: dict[str, Any]  # role -> key (per flight) or list of keys (campaign)
    upstream_stages: dict[str, str]  # role -> stage name of the upstream step
    canonical: bytes  # the canonical text of the document the key hashes
    model_ref: dict[str, Any] | None = None
    seed: dict[str, Any] | None = None
    source: dict[str, Any] | None = None
    pipeline_ref: dict[str, Any] | None = None
    flights: tuple[str, ...] = ()
    # (campaign stage, role) of each brief of this task's result a campaign task takes
    # (`Stage.brief`); not part of the key or of the stored task
    briefs: tuple[tuple[str, str], ...] = ()
    # the config's folder, where the step's options name code in it (a metric's
    # ``module:function``): the worker imports it from there; not part of the key
    code_dir: str | None = None

    @property
    def document(self) -> dict[str, Any]:
        """The document the key hashes, in plain JSON types (parsed on each access)."""
        document: dict[str, Any] = json.loads(self.canonical)
        return document

    @property
    def upstream_keys(self) -> list[str]:
        out: list[str] = []
        for v in self.upstream.values():
            out += [k for k in v if k is not None] if isinstance(v, list) else [v]
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "key": self.key,
            "step": self.step,
            "stage": self.stage,
            "flight": self.flight,
            "options": self.options,
            "upstream": self.upstream,
            "upstream_stages": self.upstream_stages,
            "model_ref": self.model_ref,
            "seed": self.seed,
            "source": self.source,
            "pipeline_ref": self.pipeline_ref,
            "flights": list(self.flights),
            **({"code_dir": self.code_dir} if self.code_dir else {}),
        }

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], document: Mapping[str, Any]) -> Task:
        return cls(
            key=doc["key"],
            step=doc["step"],
            stage=doc["stage"],
            flight=doc["flight"],
            options=dict(doc["options"]),
            upstream=dict(doc["upstream"]),
            upstream_stages=dict(doc["upstream_stages"]),
            canonical=canonical_json(document),
            model_ref=doc.get("model_ref"),
            seed=doc.get("seed"),
            source=doc.get("source"),
            pipeline_ref=doc.get("pipeline_ref"),
            flights=tuple(doc.get("flights", ())),
            code_dir=doc.get("code_dir"),
        )
