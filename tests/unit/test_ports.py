"""The UDP ports of every instance (sitl/process/ports.py): PX4 SITL's below 40, and from there on a block that collides
with nothing, so that no drone hears another's API traffic; the limits both sides draw from the sysids."""

from __future__ import annotations

import subprocess
import sys
from itertools import combinations

import pytest

from gcs.fleet.harness import LAST_INSTANCE, MAX_DRONES
from gcs.mavlink.transport import GCS_SYSID
from sitl.cli import _links, build_parser
from sitl.harness.simulation import MAX_INSTANCES
from sitl.process.ports import GCS_REMOTE_PORT, INSTANCES, MAX_INSTANCE, InstancePorts, instance_ports
from sitl.world.shared import MAX_DRONES as WORLD_ROWS

ALL = [instance_ports(i) for i in range(INSTANCES)]


def test_instances_0_to_39_keep_px4_sitl_numbers_exactly() -> None:
    for i in range(40):
        assert instance_ports(i) == InstancePorts(api_bind=14580 + i, api_remote=14540 + i, gcs_bind=18570 + i)


def test_from_instance_40_the_api_link_binds_16000_plus_i_and_streams_to_15000_plus_i() -> None:
    for i in range(40, INSTANCES):
        assert instance_ports(i) == InstancePorts(api_bind=16000 + i, api_remote=15000 + i, gcs_bind=18570 + i)
    assert instance_ports(40).api_remote == 15040 and instance_ports(253).api_bind == 16253


def test_no_two_instances_bind_the_same_port() -> None:
    binds = [p for ports in ALL for p in (ports.api_bind, ports.gcs_bind)]
    assert len(binds) == len(set(binds)) == 2 * INSTANCES


def test_no_two_instances_stream_their_api_link_to_the_same_port() -> None:
    remotes = [ports.api_remote for ports in ALL]
    assert len(set(remotes)) == INSTANCES


def test_no_drone_streams_its_api_link_to_a_port_any_drone_binds() -> None:
    binds = {p for ports in ALL for p in (ports.api_bind, ports.gcs_bind)}
    for i, ports in enumerate(ALL):
        assert ports.api_remote not in binds, i
    # the pairwise form of the same, for the failure message: drone a's stream never reaches drone b's sockets
    for a, b in combinations(range(INSTANCES), 2):
        assert ALL[a].api_remote not in (ALL[b].api_bind, ALL[b].gcs_bind), (a, b)
        assert ALL[b].api_remote not in (ALL[a].api_bind, ALL[a].gcs_bind), (a, b)


def test_no_drone_binds_the_ground_station_port_and_only_px4s_instance_10_streams_there() -> None:
    assert all(GCS_REMOTE_PORT not in (p.api_bind, p.gcs_bind) for p in ALL)
    assert [i for i, p in enumerate(ALL) if p.api_remote == GCS_REMOTE_PORT] == [10]  # PX4's own numbers


def test_every_port_is_a_valid_unprivileged_udp_port() -> None:
    assert all(1024 <= p < 65536 for ports in ALL for p in (ports.api_bind, ports.api_remote, ports.gcs_bind))


@pytest.mark.parametrize("instance", [-1, MAX_INSTANCE + 1, 255])
def test_an_instance_beyond_the_sysids_has_no_ports(instance: int) -> None:
    with pytest.raises(ValueError, match=f"instance must be in 0..{MAX_INSTANCE}"):
        instance_ports(instance)


def test_the_command_line_gives_every_instance_its_ports_by_default() -> None:
    args = build_parser().parse_args(["--instances", f"0-{MAX_INSTANCE}"])
    for i in range(INSTANCES):
        api, gcs = _links(args, i)
        ports = instance_ports(i)
        assert (api.bind[1], api.remote, gcs.bind[1]) == (ports.api_bind, ("127.0.0.1", ports.api_remote),
                                                          ports.gcs_bind), i  # fmt: skip
        assert gcs.remote == ("127.0.0.1", GCS_REMOTE_PORT)


def test_the_ground_station_and_the_simulation_agree_on_the_instances() -> None:
    """The ground station imports nothing of the simulation, so it declares the limit itself: sysids 1..254, 255
    being its own."""
    assert MAX_DRONES == GCS_SYSID - 1 == INSTANCES == MAX_INSTANCES
    assert LAST_INSTANCE == MAX_INSTANCE == 253
    assert MAX_INSTANCES <= WORLD_ROWS  # one shared-world row each


def test_the_old_path_still_gives_the_ports_and_says_where_they_moved() -> None:
    # scripts written against sitl.ports (the examples of earlier releases) keep working, told once where to go
    code = "from sitl.ports import instance_ports; print(instance_ports(3).api_bind)"
    result = subprocess.run([sys.executable, "-W", "always::DeprecationWarning", "-c", code], capture_output=True,
                            text=True, timeout=60)  # fmt: skip
    assert result.returncode == 0 and result.stdout.strip() == "14583", result
    assert "sitl.ports moved to sitl.process.ports" in result.stderr
