"""A sweep's runs on a Ray cluster (``swarm sweep --ray auto|ADDRESS``; Ray is the optional ``[cluster]`` extra).

Each run is one Ray task sized by its drones: ``num_cpus`` is the number of drone processes the run starts (one CPU
each, ``DRONES_PER_CPU`` drones to a process), so Ray places as many runs on a node as it has CPUs for. A task flies
its run exactly as the local runner does, on instances it locks on its own node, into a temporary folder, and
returns the run's result with its whole folder (report, logs) packed, which the driver unpacks under --out as the
results come: the nodes need this package installed, not a shared file system. A task whose node dies (or whose
worker is killed) is flown again elsewhere, up to ``MAX_RETRIES`` times: Ray's retries of system failures. A run
that fails in the swarm's own code is no system failure; it comes back as a failed run, as locally.
"""

from __future__ import annotations

import io
import logging
import shutil
import tarfile
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any, Final

from gcs.sweep.instance_locks import InstanceLocks
from gcs.sweep.plan import Axis, Run, SweepError, SweepPlan
from gcs.sweep.runs import Flight, RunResult, fly
from gcs.sweep.sweep import cpus_per_run

MAX_RETRIES: Final = 3
WAIT_S: Final = 0.5


def _plan_from(data: dict[str, Any], mission: Path) -> SweepPlan:
    return SweepPlan(mission=mission, mission_sha256=data["mission_sha256"], n_drones=int(data["n_drones"]),
                     seeds=tuple(data["seeds"]), fly_args=tuple(data["fly_args"]),
                     axes=tuple(Axis(a["name"], tuple(a["values"])) for a in data["axes"]))  # fmt: skip


def fly_on_node(
    plan_data: dict[str, Any], mission_text: bytes, run_data: dict[str, Any]
) -> tuple[dict[str, Any], bytes]:
    """The Ray task: fly one run of the plan on this node; its result and its folder as a .tar.gz."""
    with tempfile.TemporaryDirectory(prefix="swarm-sweep-run-") as tmp:
        mission = Path(tmp) / "mission.toml"
        mission.write_bytes(mission_text)
        plan = _plan_from(plan_data, mission)
        run = Run(index=int(run_data["index"]), seed=int(run_data["seed"]),
                  setting=tuple((str(n), float(v)) for n, v in run_data["setting"]))  # fmt: skip
        folder = Path(tmp) / "run"
        with InstanceLocks(plan.n_drones).block() as block:
            result = fly(plan, run, folder, block.first, lock_fds=block.fds)
        packed = io.BytesIO()
        with tarfile.open(fileobj=packed, mode="w:gz") as tar:
            tar.add(folder, arcname=".")
        return result.to_json(), packed.getvalue()


def _unpack(archive: bytes, into: Path) -> None:
    """The run's folder as the node left it, over the driver's: what the driver put there before (a falsification's
    mission file and scenario) stays, a report from an earlier attempt goes."""
    shutil.rmtree(into / "report", ignore_errors=True)
    into.mkdir(parents=True, exist_ok=True)
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        tar.extractall(into, filter="data")


class RayFlyer:
    """Flights as Ray tasks on the cluster at ``address`` (``auto``: the one this machine belongs to), joined at the
    first call and left at ``close``: a falsification calls it again and again."""

    def __init__(self, address: str, drones_per_process: int, say: Callable[[str], None]) -> None:
        try:
            import ray
        except ImportError:
            raise SweepError("--ray needs Ray, an optional extra: pip install 'swarmsitl[cluster]' (or ray)") from None
        self._ray = ray
        self.address = address
        self.drones_per_process = drones_per_process
        self.say = say
        self._task: Any = None
        self._cpus = 0.0
        self._joining = threading.Lock()  # a falsification's shrinking passes may make their first calls at once

    def _join(self) -> None:
        ray = self._ray
        try:
            ray.init(address=self.address, log_to_driver=False, logging_level=logging.ERROR)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise SweepError(f"--ray {self.address}: no Ray cluster to join ({first}); start one with ray start "
                             "--head") from None  # fmt: skip
        self._cpus = ray.cluster_resources().get("CPU", 0)
        self._task = ray.remote(max_retries=MAX_RETRIES, retry_exceptions=False)(fly_on_node)

    def __call__(self, flights: list[Flight], finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        ray = self._ray
        with self._joining:
            if self._task is None:
                self._join()
                if flights:
                    cpus = cpus_per_run(flights[0].plan.n_drones, self.drones_per_process)
                    self.say(f"sweep: Ray cluster at {self.address}: {self._cpus:g} CPUs, {cpus} per run, up to "
                             f"{int(self._cpus // cpus)} runs at once")  # fmt: skip
        refs: dict[Any, Flight] = {}
        try:
            for flight in flights:
                cpus = cpus_per_run(flight.plan.n_drones, self.drones_per_process)
                if self._cpus < cpus:
                    raise SweepError(f"--ray {self.address}: a run needs {cpus} CPUs, the cluster has {self._cpus:g}")
                run = {
                    "index": flight.run.index,
                    "seed": flight.run.seed,
                    "setting": [list(s) for s in flight.run.setting],
                }
                ref = self._task.options(num_cpus=cpus).remote(
                    flight.plan.to_json(), flight.plan.mission.read_bytes(), run
                )
                refs[ref] = flight
            while refs and not stop.is_set():  # stopped: the runs under way are cancelled below, as the local flyer's
                ready, _ = ray.wait(list(refs), num_returns=1, timeout=WAIT_S)
                for ref in ready:
                    flight = refs.pop(ref)
                    data, archive = ray.get(ref)
                    _unpack(archive, flight.folder)
                    command = list(data["command"])  # the report's path on this machine, not the node's
                    command[command.index("--report") + 1] = str(flight.folder / "report")
                    finished(RunResult.from_json({**data, "command": command}))
        finally:
            for ref in refs:
                ray.cancel(ref)  # the task's run stops its swarm (its flight ends as on Ctrl-C)

    def close(self) -> None:
        if self._task is not None:
            self._ray.shutdown()
            self._task = None
