"""The flights of a campaign as planned: each flight's name, source, loader options
and own model, in config order (`planning.plan` keys them)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import AeroidError, ConfigError
from ..keys import canonical_json, file_digest, sha256_hex
from .config import CampaignConfig, FileFlights, SimulatedSource


@dataclass(frozen=True)
class _Flight:
    """One flight as planned: its name, source, loader options and own model, if any."""

    name: str
    source: dict[str, Any]
    loader: dict[str, Any]
    model: dict[str, Any] | None = None  # the campaign's model with the entry's changes


def _merged(base: Mapping[str, Any], changes: Mapping[str, Any]) -> dict[str, Any]:
    """`base` with `changes` deep-merged into it (mappings merge, anything else replaces)."""
    out = dict(base)
    for k, v in changes.items():
        old = out.get(k)
        out[k] = _merged(old, v) if isinstance(old, Mapping) and isinstance(v, Mapping) else v
    return out


def _flight_model(config: CampaignConfig, i: int, spec: FileFlights) -> dict[str, Any] | None:
    """The model of file entry `i`: None for the campaign's, else its changes merged in."""
    if spec.model is None:
        return None
    if not isinstance(config.model, Mapping):
        raise ConfigError(
            f"{config.source}: flights[{i}].model: changes a model mapping, but the "
            f"campaign's model is {config.model!r}; give the model as an aeroid.models.aircraft "
            "mapping (aircraft: ...) to give flights their own"
        )
    return _merged(config.model, spec.model)


def _windows(config: CampaignConfig, i: int, path: Path, spec: FileFlights) -> list[list[float]]:
    """The manoeuvre windows `spec.segments` finds in `path`, each a flight's window."""
    from ...io.channel_map import flight_windows

    assert spec.segments is not None
    segments = spec.segments.model_dump(mode="json", exclude_none=True)
    try:
        found = flight_windows(
            path,
            segments,
            channels=spec.loader_options().get("channels"),
            time_column=spec.time_column,
        )
    except AeroidError as exc:
        raise ConfigError(f"{config.source}: flights[{i}].segments ({path}): {exc}") from None
    if not found:
        raise ConfigError(f"{config.source}: flights[{i}].segments: no manoeuvre found in {path}")
    return [[float(t0), float(t1)] for t0, t1 in found]


def _flight_sources(
    config: CampaignConfig, source_texts: dict[int, bytes] | None = None
) -> list[_Flight]:
    """Every flight, in config order (a file's segments: one flight per window).

    `source_texts` receives the canonical text of each simulated flight's spec, by
    the spec's id, so planning serialises each spec once."""
    return list(_iter_flight_sources(config, source_texts))


def _iter_flight_sources(
    config: CampaignConfig,
    source_texts: dict[int, bytes] | None = None,
    files: list[tuple[int, Path, FileFlights]] | None = None,
) -> Iterator[_Flight]:
    """The flights of `_flight_sources`, one at a time (`files`: the config's
    `expand_files`, where the caller has it already)."""
    from .synthetic import flight_spec

    if source_texts is None:
        source_texts = {}
    if files is None:
        files = config.expand_files()
    stems = Counter(p.stem for _, p, _ in files)
    by_entry: dict[int, list[tuple[int, Path, FileFlights]]] = {}
    for f in files:
        by_entry.setdefault(f[0], []).append(f)
    for i, item in enumerate(config.flights):
        if isinstance(item, SimulatedSource):
            spec = item.simulated.model_dump(mode="json")
            width = len(str(spec["n_flights"] - 1))
            for j in range(spec["n_flights"]):
                fs = flight_spec(spec, j)
                text = canonical_json(fs)
                source = {"kind": "simulated", "spec": fs, "sha256": sha256_hex(text)}
                source_texts[id(fs)] = text
                yield _Flight(f"sim-{j:0{width}d}", source, {})
            continue
        for _, path, loader in by_entry.get(i, ()):
            opts = loader.loader_options()
            if loader.condition is not None:
                # engine-only: the load stage merges it into the flight's metadata
                opts["condition"] = dict(loader.condition)
            model = _flight_model(config, i, loader)
            name = path.stem
            if stems[path.stem] > 1:
                base = Path(config.base_dir)
                name = str(path.relative_to(base)) if path.is_relative_to(base) else str(path)
            try:
                digest = file_digest(path)
            except OSError as exc:
                # unreadable now: the load task fails and says why; nothing is cached
                digest = "unreadable:" + sha256_hex(f"{path}:{exc}".encode())
            source = {"kind": "file", "path": str(path), "sha256": digest}
            if loader.segments is None:
                yield _Flight(name, source, opts, model)
                continue
            windows = _windows(config, i, path, loader)
            width = len(str(len(windows)))
            for k, window in enumerate(windows, 1):
                seg_opts = {**opts, "window": window}
                yield _Flight(f"{name}-seg{k:0{width}d}", source, seg_opts, model)
