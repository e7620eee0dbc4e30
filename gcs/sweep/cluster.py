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

from gcs.sweep.plan import Axis, Run, SweepError, SweepPlan
from gcs.sweep.runs import InstanceLocks, RunResult, fly
from gcs.sweep.sweep import Flyer, cpus_per_run, run_dir

MAX_RETRIES: Final = 3
WAIT_S: Final = 0.5


def _plan_from(data: dict[str, Any], mission: Path) -> SweepPlan:
    return SweepPlan(mission=mission, mission_sha256=data["mission_sha256"], n_drones=int(data["n_drones"]),
                     seeds=tuple(data["seeds"]), fly_args=tuple(data["fly_args"]),
                     axes=tuple(Axis(a["name"], tuple(a["values"])) for a in data["axes"]))  # fmt: skip


def fly_on_node(plan_data: dict[str, Any], mission_text: bytes, index: int) -> tuple[dict[str, Any], bytes]:
    """The Ray task: fly run ``index`` of the plan on this node; its result and its folder as a .tar.gz."""
    with tempfile.TemporaryDirectory(prefix="swarm-sweep-run-") as tmp:
        mission = Path(tmp) / "mission.toml"
        mission.write_bytes(mission_text)
        plan = _plan_from(plan_data, mission)
        run = plan.runs()[index]
        folder = Path(tmp) / "run"
        with InstanceLocks(plan.n_drones).block() as block:
            result = fly(plan, run, folder, block.first, lock_fds=block.fds)
        packed = io.BytesIO()
        with tarfile.open(fileobj=packed, mode="w:gz") as tar:
            tar.add(folder, arcname=".")
        return result.to_json(), packed.getvalue()


def _unpack(archive: bytes, into: Path) -> None:
    shutil.rmtree(into, ignore_errors=True)
    into.mkdir(parents=True)
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:gz") as tar:
        tar.extractall(into, filter="data")


def ray_flyer(plan: SweepPlan, out: Path, address: str, drones_per_process: int,
              say: Callable[[str], None]) -> Flyer:  # fmt: skip
    """Runs as Ray tasks on the cluster at ``address`` (``auto``: the one this machine belongs to)."""
    try:
        import ray
    except ImportError:
        raise SweepError("--ray needs Ray, an optional extra: pip install 'swarmsitl[cluster]' (or ray)") from None

    def flyer(pending: list[Run], finished: Callable[[RunResult], None], stop: threading.Event) -> None:
        try:
            ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
        except (ConnectionError, RuntimeError, ValueError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise SweepError(f"--ray {address}: no Ray cluster to join ({first}); start one with ray start --head") \
                from None  # fmt: skip
        refs: dict[Any, Run] = {}
        try:
            cpus = cpus_per_run(plan.n_drones, drones_per_process)
            total = ray.cluster_resources().get("CPU", 0)
            say(f"sweep: Ray cluster at {address}: {total:g} CPUs, {cpus} per run, up to {int(total // cpus)} runs "
                f"at once")  # fmt: skip
            if total < cpus:
                raise SweepError(f"--ray {address}: a run needs {cpus} CPUs, the cluster has {total:g}")
            task = ray.remote(num_cpus=cpus, max_retries=MAX_RETRIES, retry_exceptions=False)(fly_on_node)
            mission_text = plan.mission.read_bytes()
            plan_data = plan.to_json()
            refs = {task.remote(plan_data, mission_text, run.index): run for run in pending}
            while refs:
                if stop.is_set():
                    raise KeyboardInterrupt
                ready, _ = ray.wait(list(refs), num_returns=1, timeout=WAIT_S)
                for ref in ready:
                    run = refs.pop(ref)
                    data, archive = ray.get(ref)
                    folder = run_dir(out, run)
                    _unpack(archive, folder)
                    command = list(data["command"])  # the report's path on this machine, not the node's
                    command[command.index("--report") + 1] = str(folder / "report")
                    finished(RunResult.from_json({**data, "command": command}))
        except BaseException:
            for ref in refs:
                ray.cancel(ref)  # the task's run stops its swarm (its flight ends as on Ctrl-C)
            raise
        finally:
            ray.shutdown()

    return flyer
