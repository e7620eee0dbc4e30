"""How a swarm's drones are shared out between simulation processes, and the command lines that start them."""

from __future__ import annotations

from pathlib import Path

import pytest

from gcs.composition import launch_plan
from gcs.fleet.harness import SpawnPlan
from sitl.cli import build_parser, parse_instances
from sitl.dynamics.plant import DEFAULT_HOME, GeoPoint
from sitl.harness.processes import LaunchPlan, host_args, host_groups, sitl_args


def test_fixed_hosts_take_runs_of_k_consecutive_drones() -> None:
    assert host_groups(7, 3, usable_cpus=2) == [[0, 1, 2], [3, 4, 5], [6]]
    assert host_groups(2, 1, usable_cpus=8) == [[0], [1]]
    assert host_groups(3, 10, usable_cpus=1) == [[0, 1, 2]]


def test_auto_makes_one_host_per_usable_cpu_sizes_within_one() -> None:
    assert host_groups(9, "auto", usable_cpus=2) == [[0, 1, 2, 3, 4], [5, 6, 7, 8]]
    assert [len(g) for g in host_groups(50, "auto", usable_cpus=4)] == [13, 13, 12, 12]
    assert host_groups(1, "auto", usable_cpus=4) == [[0]]  # never an empty host


def test_a_process_hosts_at_least_one_drone() -> None:
    with pytest.raises(ValueError, match="at least one drone"):
        host_groups(3, 0, usable_cpus=2)


def test_a_host_starts_its_drones_as_each_would_be_started_alone(tmp_path: Path) -> None:
    """Same seeds, homes, cameras, clock, world and links: ``sitl --instances`` with the host's arguments and
    ``sitl --instance`` with each drone's give the same per-drone settings."""
    plan = LaunchPlan(origin=DEFAULT_HOME, offsets_ne_m=((0.0, 0.0), (0.0, 2.0), (2.0, 0.0)), lockstep=True,
                      lockstep_quantum=8, first_instance=40, seed=5, log_dir=tmp_path, camera_drones=frozenset({2}),
                      camera_dir=tmp_path / "camera", drones_per_process=3)  # fmt: skip
    homes = plan.homes()
    hosted = build_parser().parse_args(host_args(plan, [40, 41, 42], homes, 14550, "world"))
    assert parse_instances(hosted.instances) == [40, 41, 42] and hosted.log_dir == tmp_path
    assert hosted.camera_frames == tmp_path / "camera" and parse_instances(hosted.camera_instances) == [41]
    for k, instance in enumerate([40, 41, 42]):
        alone = build_parser().parse_args(sitl_args(plan, instance, homes[k], 14550, "world"))
        assert alone.seed == hosted.seed + k and alone.home == [hosted.home[k]]
        for option in ("speed", "gcs_remote", "airframe", "world", "lockstep", "lockstep_quantum"):
            assert getattr(alone, option) == getattr(hosted, option), option
        expected_camera = tmp_path / "camera" / f"drone-{instance}" if instance == 41 else None
        assert alone.camera_frames == expected_camera


def test_a_plan_with_a_signing_key_starts_every_drone_signing_and_requiring_signatures(tmp_path: Path) -> None:
    key_file = tmp_path / "swarm.key"
    plan = launch_plan(SpawnPlan(n_drones=3, first_instance=40, signing_key_file=key_file))
    homes = plan.homes()
    for args in (host_args(plan, [40, 41, 42], homes, 14550, None), sitl_args(plan, 40, homes[0], 14550, None)):
        parsed = build_parser().parse_args(args)
        assert parsed.signing_key == str(key_file) and parsed.signing_required
    unsigned = build_parser().parse_args(sitl_args(launch_plan(SpawnPlan(n_drones=1)), 0, homes[0], 14550, None))
    assert unsigned.signing_key is None and not unsigned.signing_required


def test_an_origin_south_and_west_and_a_wind_to_the_south_west_reach_every_drone_as_given() -> None:
    """Values with a minus sign in front: argparse takes ``-33.9,151.2,10`` after ``--home`` for an option of its own
    unless the value is joined to its option."""
    origin = GeoPoint(lat_deg=-33.856784, lon_deg=-70.658333, alt_amsl_m=520.0)
    plan = LaunchPlan(origin=origin, offsets_ne_m=((0.0, 0.0), (0.0, 2.0)), first_instance=40,
                      wind_ned_mps=(-1.5, -0.25, 0.0), gust_mps=0.5)  # fmt: skip
    homes = plan.homes()
    for args in (host_args(plan, [40, 41], homes, 14550, None), sitl_args(plan, 40, homes[0], 14550, None)):
        parsed = build_parser().parse_args(args)
        assert (parsed.wind, parsed.gust) == ("-1.5,-0.25,0.0", 0.5)
        lat, lon, alt = (float(v) for v in parsed.home[0].split(","))
        assert (round(lat, 6), round(lon, 6), alt) == (-33.856784, -70.658333, 520.0)
