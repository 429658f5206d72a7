"""Every XLA compilation of a campaign run, by process (issue 47; run by hand).

    python tests/benchmarks/bench_compilations.py [CONFIG] [--workers N] [--runs N]

Runs ``python -m aeroid.cli run CONFIG`` (default: the demo, ``configs/demo.yaml``)
cold, as `bench_demo` does: a fresh process on an empty store and an empty compilation
cache. Every process of the run (the command and its workers) loads a
``sitecustomize`` module from a temporary folder put first on ``PYTHONPATH``; it
switches on JAX's compile logging (``JAX_LOG_COMPILES``) and writes each of JAX's
tracing, compiling and persistent-cache messages, with the library's frames on the
stack, to a file per process. Nothing in the library changes.

Printed, per process in the order the programs were met: the moment (wall s since the
process's first program), the stage and library function that asked for the program,
its name and argument shapes, the s JAX spent tracing it (and the functions inside it),
the wall s until the compiled program was ready and the process's CPU s meanwhile, and
how it came: ``compiled`` (XLA compiled it here), ``disk`` (found in the persistent
cache), ``shared`` (another process was compiling it: this one waited, the wall counts
the wait, the CPU does not, and read it) or ``small`` (compiled in every process:
quicker than the persistent cache's threshold). Then per program: how many processes
compiled it and how many read it, their CPU s and tracing s summed.

The CPU column is the whole process's (XLA compiles on threads of its own), tracing
excluded. The machine may be shared: read the CPU columns, and run it twice
(``--runs 2``) before drawing conclusions.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

# Loaded by every process of the run (the command and its workers): JAX's compile
# messages, with the stack's library frames, appended to <folder>/<pid>.jsonl.
_HOOK = textwrap.dedent(
    """
    import json, logging, os, threading, time, traceback

    _FOLDER = os.environ["AEROID_BENCH_COMPILES"]
    _KEEP = ("Finished tracing", "Compiling ", "Finished XLA compilation",
             "Persistent compilation cache hit")


    class _Log(logging.Handler):
        def emit(self, record):
            text = record.getMessage()
            if not text.startswith(_KEEP):
                return
            frames = [
                f"{os.path.basename(f.filename)}:{f.name}"
                for f in traceback.extract_stack()
                if "/aeroid/" in f.filename.replace(os.sep, "/")
            ]
            line = {
                "wall": time.perf_counter(),
                "cpu": time.process_time(),
                "thread": threading.get_ident(),
                "text": text[:600],
                "frames": frames,
            }
            path = os.path.join(_FOLDER, f"{os.getpid()}.jsonl")
            with open(path, "a", encoding="utf-8") as fh:
                fh.write(json.dumps(line) + "\\n")


    _handler = _Log(logging.DEBUG)
    for _name in ("jax._src.dispatch", "jax._src.interpreters.pxla", "jax._src.compiler"):
        _logger = logging.getLogger(_name)
        _logger.addHandler(_handler)
        _logger.setLevel(logging.DEBUG)
        _logger.propagate = False  # the run's stderr stays as it is
    """
)

_NAME = re.compile(r"(?:of |Compiling )(jit\([^)]*\))")
_SECONDS = re.compile(r"in ([0-9.]+) sec")
_SHAPES = re.compile(r"ShapedArray\(([a-z0-9]+\[[0-9,]*\])")


def _stage(frames: list[str]) -> str:
    """The pipeline stage on the stack (the deepest ``_run_<stage>`` function), else '-'."""
    for f in reversed(frames):
        fn = f.split(":", 1)[1]
        if fn.startswith("_run_"):
            return fn[len("_run_") :]
    return "-"


def _caller(frames: list[str]) -> str:
    """The deepest library frame outside the compiled-program helpers."""
    for f in reversed(frames):
        if not f.startswith(("_jax_translation.py", "jax_compiled.py")):
            return f
    return frames[-1] if frames else "-"


def _programs(lines: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One entry per program a process met: paired from its log lines, thread by thread."""
    open_: dict[int, dict[str, Any]] = {}
    traced: dict[int, float] = defaultdict(float)
    hits: dict[int, bool] = defaultdict(bool)
    out: list[dict[str, Any]] = []
    for ln in lines:
        text, thread = ln["text"], ln["thread"]
        if text.startswith("Finished tracing"):
            s = _SECONDS.search(text)
            traced[thread] += float(s.group(1)) if s else 0.0
        elif text.startswith("Compiling "):
            m = _NAME.search(text)
            name = m.group(1) if m else "?"
            open_[thread] = {
                "name": name,
                "shapes": " ".join(_SHAPES.findall(text)),
                "trace": traced.pop(thread, 0.0),
                "wall0": ln["wall"],
                "cpu0": ln["cpu"],
                "stage": _stage(ln["frames"]),
                "caller": _caller(ln["frames"]),
            }
            hits[thread] = False
        elif text.startswith("Persistent compilation cache hit"):
            hits[thread] = True
        elif text.startswith("Finished XLA compilation") and thread in open_:
            entry = open_.pop(thread)
            s = _SECONDS.search(text)
            entry["compile"] = float(s.group(1)) if s else ln["wall"] - entry["wall0"]
            entry["cpu"] = ln["cpu"] - entry.pop("cpu0")
            entry["how"] = "disk" if hits[thread] else "compiled"
            out.append(entry)
    return out


def _run(config: Path, workers: int | None, folder: Path) -> tuple[float, dict[int, list[Any]]]:
    """One cold run with the hook: (wall s, pid -> its programs)."""
    hook, logs = folder / "hook", folder / "logs"
    hook.mkdir()
    logs.mkdir()
    (hook / "sitecustomize.py").write_text(_HOOK, encoding="utf-8")
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(hook), str(ROOT)]),
        AEROID_JAX_CACHE=str(folder / "jax"),
        AEROID_BENCH_COMPILES=str(logs),
        JAX_LOG_COMPILES="1",
    )
    cmd = [sys.executable, "-m", "aeroid.cli", "run", str(config), "-q"]
    if workers is not None:
        cmd += ["--workers", str(workers)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, env=env, cwd=config.parent, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"aeroid run failed ({done.returncode}):\n{done.stderr[-3000:]}")
    out: dict[int, list[Any]] = {}
    for path in sorted(logs.glob("*.jsonl")):
        lines = [json.loads(t) for t in path.read_text(encoding="utf-8").splitlines() if t]
        out[int(path.stem)] = _programs(lines)
    return wall, out


def _cache_threshold() -> float:
    from aeroid.models import jax_compiled

    return float(jax_compiled._CACHE_MIN_SECONDS)


def _classify(by_pid: dict[int, list[Any]]) -> None:
    """Name how each process came by each program: of the processes that did not find it
    on disk, the one that spent the most CPU compiled it; one that spent under half of
    that waited for it (the library's lock per program) and read it; a program quicker
    to compile than the persistent cache's threshold is compiled by each ('small')."""
    small = _cache_threshold()
    most: dict[tuple[str, str], float] = defaultdict(float)
    for programs in by_pid.values():
        for p in programs:
            if p["how"] == "compiled":
                key = (p["name"], p["shapes"])
                most[key] = max(most[key], p["cpu"])
    for programs in by_pid.values():
        for p in programs:
            if p["how"] != "compiled":
                continue
            if p["cpu"] < 0.5 * most[(p["name"], p["shapes"])]:
                p["how"] = "shared"
            elif p["compile"] < small:
                p["how"] = "small"


def _report(wall: float, by_pid: dict[int, list[Any]]) -> None:
    _classify(by_pid)
    print(f"run: {wall:.1f} s wall; {len(by_pid)} process(es) met compiled programs")
    totals: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0, 0, 0, 0.0, 0.0])
    for n, (pid, programs) in enumerate(sorted(by_pid.items()), start=1):
        if not programs:
            continue
        start = min(p["wall0"] for p in programs)
        print(f"process {n} (pid {pid}):")
        print(
            f"  {'at s':>6} {'stage':10} {'program':24} {'trace':>6} {'ready':>6} {'cpu':>6}  "
            "how       asked by / shapes"
        )
        for p in programs:
            how = p["how"]
            print(
                f"  {p['wall0'] - start:6.1f} {p['stage'][:10]:10} {p['name'][:24]:24} "
                f"{p['trace']:6.2f} {p['compile']:6.2f} {p['cpu']:6.2f}  {how:8}  "
                f"{p['caller']}\n{'':60}{p['shapes'][:110]}"
            )
            t = totals[(p["name"], p["shapes"])]
            t[0 if how in ("compiled", "small") else 1] += 1
            t[2] += 1
            t[3] += p["cpu"]
            t[4] += p["trace"]
    print(
        "per program (name, shapes): compiled / read (disk or shared) in processes, CPU s, tracing s"
    )
    for (name, shapes), (comp, read, _, cpu, trace) in sorted(
        totals.items(), key=lambda kv: -kv[1][3]
    ):
        print(f"  {name[:24]:24} {comp:2d} / {read:2d}  {cpu:6.2f}  {trace:6.2f}  {shapes[:70]}")
    cpu = sum(t[3] for t in totals.values())
    trace = sum(t[4] for t in totals.values())
    print(f"  all: {cpu:.2f} s CPU compiling or reading, {trace:.2f} s tracing")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", nargs="?", type=Path, default=ROOT / "configs" / "demo.yaml")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--runs", type=int, default=1)
    args = ap.parse_args()
    for _ in range(args.runs):
        folder = Path(tempfile.mkdtemp(prefix="aeroid-bench-compilations-"))
        try:
            config = _copied(args.config.resolve(), folder)
            wall, by_pid = _run(config, args.workers, folder)
            _report(wall, by_pid)
        finally:
            shutil.rmtree(folder, ignore_errors=True)


def _copied(config: Path, folder: Path) -> Path:
    """`config`'s folder copied into `folder`, its store and report inside it."""
    shutil.copytree(config.parent, folder / "configs")
    path = folder / "configs" / config.name
    text = path.read_text(encoding="utf-8")
    text = re.sub(r"(?m)^store: .*$", f"store: {folder / 'store'}", text)
    text = re.sub(r"(?m)^report: .*$", f"report: {folder / 'report' / 'run.md'}", text)
    path.write_text(text, encoding="utf-8")
    return path


if __name__ == "__main__":
    main()
