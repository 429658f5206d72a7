"""A campaign on dask.distributed with its store on S3 (issue 49): 1,000 tiny flights.

The flights are `bench_campaign_scale`'s (simulated, 2 s at 10 Hz, loaded and
reduced to their means by a one-line stage: two tasks a flight), so what is
measured is the engine. The S3 server is moto's, on loopback, in a process of
its own that counts the requests it serves (by method; a GET with
``list-type`` is a listing); the cluster is a `distributed.LocalCluster` of
worker processes (2 workers x 1 thread; its scheduler runs in this process,
beside the run that plans and collects). In turn, each on a fresh store:

1. the local pool (the default executor) on a folder: the reference;
2. the cluster on a folder: the scheduler's cost over the local pool;
3. the cluster on S3, with one worker killed (SIGKILL) once a third of the
   results are stored: its nanny starts another and the run goes on;
4. an unchanged rerun of 3 (requests: listings and the index only).

Reported: wall and CPU seconds (this process: planning, collecting, and for
2 and 3 the scheduler; the S3 server's own), flights an hour, the per-task
overhead (wall x workers - time in the stages, over tasks), requests per
stored result, and whether the S3 store's arrays are bit-identical to the
reference's. Usage: ``python tests/benchmarks/bench_campaign_cluster.py
[--flights 1000]`` (needs distributed, s3fs and moto[server]).
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_campaign_scale import TINY, _config

_CREDENTIALS = {
    "AWS_ACCESS_KEY_ID": "testing",
    "AWS_SECRET_ACCESS_KEY": "testing",
    "AWS_DEFAULT_REGION": "us-east-1",
}

# the S3 server: moto's, counting the requests it serves; "count" on stdin prints the
# counts and its CPU seconds, "reset" clears the counts
_SERVER = """\
import collections, json, logging, resource, sys
from moto.moto_server import threaded_moto_server as t

logging.getLogger("werkzeug").setLevel(logging.ERROR)  # no line a request on stderr

counts = collections.Counter()


class Counting(t.DomainDispatcherApplication):
    def __call__(self, environ, start_response):
        method = environ.get("REQUEST_METHOD", "?")
        if method == "GET" and "list-type" in environ.get("QUERY_STRING", ""):
            method = "LIST"
        counts[method] += 1
        return super().__call__(environ, start_response)


t.DomainDispatcherApplication = Counting
server = t.ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
server.start()
host, port = server.get_host_and_port()
print(f"http://{host}:{port}", flush=True)
for line in sys.stdin:
    if line.strip() == "reset":
        counts.clear()
    ru = resource.getrusage(resource.RUSAGE_SELF)
    print(json.dumps({"counts": dict(counts), "cpu": ru.ru_utime + ru.ru_stime}), flush=True)
"""


class _Server:
    """The S3 server process and its request counts."""

    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _SERVER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.proc.stdout is not None
        self.endpoint = self.proc.stdout.readline().strip()
        self._lock = threading.Lock()

    def ask(self, what: str = "count") -> dict[str, Any]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        with self._lock:
            self.proc.stdin.write(what + "\n")
            self.proc.stdin.flush()
            doc: dict[str, Any] = json.loads(self.proc.stdout.readline())
        return doc

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(timeout=30)


def _cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def _arrays(store: Any) -> dict[str, dict[str, bytes]]:
    out = {}
    for entry in store.entries():
        arrays = store.load_arrays(entry.key, entry.stage)
        out[entry.key] = {n: a.dtype.str.encode() + a.tobytes() for n, a in arrays.items()}
    return out


def _timed_run(label: str, n: int, workers: int, **kwargs: Any) -> Any:
    from aeroid.pipeline import run

    cpu, t0 = _cpu(), time.perf_counter()
    summary = run(**kwargs)
    wall, cpu = time.perf_counter() - t0, _cpu() - cpu
    tasks = len(summary.ledger)
    compute = summary.seconds["compute"]
    computed = summary.count("computed")
    overhead = f"{1e3 * (wall * workers - compute) / computed:.1f} ms" if computed else "-"
    print(
        f"{label}: {wall:.1f} s wall, {cpu:.1f} s CPU in this process; "
        f"{summary.count('computed')} computed, {summary.count('cached')} cached, "
        f"{summary.failed} failed of {tasks} tasks; {3600 * n / wall:,.0f} flights an hour; "
        f"overhead {overhead} a task ({1e3 * compute / tasks:.2f} ms in stages)",
        flush=True,
    )
    return summary, wall


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--flights", type=int, default=1000)
    args = parser.parse_args()
    n = args.flights
    import distributed
    import s3fs

    from aeroid.pipeline import open_store

    work = Path(tempfile.mkdtemp(prefix="aeroid-bench-cluster-"))
    server = _Server()
    os.environ.update(_CREDENTIALS)
    # the workers are other processes: they find the server through the environment
    os.environ["FSSPEC_S3_ENDPOINT_URL"] = server.endpoint
    import fsspec.config

    fsspec.config.conf["s3"] = {"endpoint_url": server.endpoint}  # read once, at import
    try:
        bucket = f"aeroid-{uuid.uuid4().hex[:12]}"
        s3fs.S3FileSystem(endpoint_url=server.endpoint).mkdir(bucket)
        s3_url = f"s3://{bucket}/store"
        (work / "tiny.py").write_text(TINY, encoding="utf-8")
        cfg = work / "campaign.yaml"
        cfg.write_text(_config(n), encoding="utf-8")
        sys.path.insert(0, str(work))  # the workers import the pipeline from there
        os.environ["PYTHONPATH"] = os.pathsep.join(
            [str(work), *filter(None, [os.environ.get("PYTHONPATH")])]
        )
        print(
            f"{n} tiny flights, cores: {len(os.sched_getaffinity(0))}, "
            f"load {os.getloadavg()[0]:.1f}",
            flush=True,
        )
        local, local_wall = _timed_run(
            "local pool, folder store", n, 2, config=cfg, store=work / "local"
        )
        # no client of its own here: the run's is the only one in this process
        with distributed.LocalCluster(
            n_workers=2,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.CRITICAL,
        ) as cluster:
            address = cluster.scheduler_address
            _, folder_wall = _timed_run(
                "cluster, folder store",
                n,
                2,
                config=cfg,
                store=work / "folder",
                scheduler=address,
            )
            pids = [w.pid for w in cluster.scheduler.workers.values()]
            open_store(s3_url, create=True)
            killed: list[float] = []
            t_start = time.perf_counter()

            def kill_a_third_in() -> None:
                # the server's PUT count says how many results are stored: no request
                deadline = time.monotonic() + 600
                while time.monotonic() < deadline and not killed:
                    if server.ask()["counts"].get("PUT", 0) >= 2 * n // 3:
                        os.kill(pids[0], signal.SIGKILL)
                        killed.append(time.perf_counter() - t_start)
                        return
                    time.sleep(0.2)

            server.ask("reset")
            before = server.ask()["cpu"]
            killer = threading.Thread(target=kill_a_third_in, daemon=True)
            killer.start()
            remote, s3_wall = _timed_run(
                "cluster, S3 store, a worker killed",
                n,
                2,
                config=cfg,
                store=s3_url,
                scheduler=address,
            )
            killer.join(timeout=5)
            served = server.ask()
            stored = remote.count("computed")
            requests = sum(served["counts"].values())
            print(
                f"worker {pids[0]} killed {killed[0]:.1f} s into the run; "
                if killed
                else "the worker was NOT killed (the run ended first); ",
                end="",
            )
            print(
                f"S3 requests: {requests} for {stored} stored results "
                f"({requests / max(1, stored):.2f} a result: {served['counts']}); "
                f"the S3 server's CPU {served['cpu'] - before:.1f} s",
                flush=True,
            )
            server.ask("reset")
            _timed_run(
                "unchanged rerun on the cluster, S3",
                n,
                2,
                config=cfg,
                store=s3_url,
                scheduler=address,
            )
            print(f"unchanged rerun: S3 requests {server.ask()['counts']}", flush=True)
        t0 = time.perf_counter()
        same = _arrays(open_store(s3_url)) == _arrays(open_store(work / "local"))
        keys_same = list(remote.statuses) == list(local.statuses)
        print(
            f"S3 store bit-identical to the local run: {same} (keys in the same order: "
            f"{keys_same}; compared in {time.perf_counter() - t0:.1f} s)",
            flush=True,
        )
        tasks = len(local.ledger)
        print(
            f"per task: the cluster costs {1e3 * (folder_wall - local_wall) * 2 / tasks:.1f} ms "
            f"of worker time over the local pool (scheduler), S3 "
            f"{1e3 * (s3_wall - folder_wall) * 2 / tasks:.1f} ms more over a folder (store, "
            "and the killed worker's lost work)",
            flush=True,
        )
        if not (same and keys_same and remote.failed == 0 and killed):
            raise SystemExit("FAILED: see above")
    finally:
        server.close()
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
