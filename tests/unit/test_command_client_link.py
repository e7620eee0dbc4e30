"""The ground station's command and parameter clients against a drone's own MAVLink services, with no socket.

Two real protocol objects joined by a fake link that can lose chosen messages: the clients of gcs/mavlink/commands.py
and gcs/mavlink/params.py on one side, the drone's link services (sitl/protocol, with a recording fake vehicle) on the
other. Time is a number both sides are given. What is checked is the conversation: a lost command is resent with its
retry count and acted on once, a lost ACK makes the drone answer the retry from its cache without acting twice, and
a value the drone refuses comes back as the value it kept.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from gcs.mavlink.commands import COMMAND_TIMEOUT_S, Ack, CommandClient, Send
from gcs.mavlink.params import PARAM_RETRIES, ParamClient
from sitl.autopilot.vehicle_api import Arm
from sitl.params import ParamDef, ParamStore
from sitl.protocol import Identity, LinkServices
from sitl.protocol.testing import FakeVehicle, Wire

SYSID = 7
ARM = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED


class LossyLink:
    """Drone ``SYSID``'s link services behind a wire each way; ``lose_up``/``lose_down`` drop chosen messages."""

    def __init__(self) -> None:
        self.vehicle = FakeVehicle()
        store = ParamStore([ParamDef(name="MIS_TAKEOFF_ALT", default=2.5, min=0.5, max=100, unit="m",
                                     description="")])  # fmt: skip
        self.drone = LinkServices(Identity(sysid=SYSID), self.vehicle, store)
        self.up = Wire()  # the ground station's ids (255/190)
        self.down = Wire(SYSID, 1)
        self.lose_up: Callable[[Any], bool] = lambda _msg: False
        self.lose_down: Callable[[Any], bool] = lambda _msg: False
        self.sent_up: list[Any] = []

    def exchange(self, effects: list[Send], now_s: float) -> list[Any]:
        """Carry the ground station's messages to the drone; what the drone answers (after losses), as received."""
        answers: list[Any] = []
        for effect in effects:
            assert effect.sysid == SYSID
            msg = self.up(effect.message)
            self.sent_up.append(msg)
            if self.lose_up(msg):
                continue
            answers += [m for m in self.down.carry(self.drone.handle(msg, now_s)) if not self.lose_down(m)]
        return answers


def run_command(link: LossyLink, client: CommandClient, command: int, params: tuple[float, ...]) -> tuple[Ack, float]:
    """Start a command at t=0 and serve it as the swarm does until it ends; the outcome and when it came."""
    now = 0.0
    inbox = link.exchange(client.start(SYSID, command, params, now), now)
    while True:
        for msg in inbox:
            client.handle(msg, now)
        if (ack := client.take(SYSID, command)) is not None:
            return ack, now
        now = client.next_due_s()
        inbox = link.exchange(client.poll(now), now)


def test_a_lost_command_is_resent_with_its_retry_count_and_acted_on_once() -> None:
    # GIVEN a link that loses the first COMMAND_LONG
    link = LossyLink()
    link.lose_up = lambda msg: msg.get_type() == "COMMAND_LONG" and msg.confirmation == 0
    # WHEN the ground station arms the drone
    ack, at_s = run_command(link, CommandClient(), ARM, (1.0,))
    # THEN the retry (confirmation 1) after one timeout is accepted and the vehicle was asked once
    assert ack == Ack(SYSID, ACCEPTED) and at_s == COMMAND_TIMEOUT_S
    assert [m.confirmation for m in link.sent_up] == [0, 1]
    assert link.vehicle.requests == [Arm(force=False)]


def test_a_lost_ack_is_answered_again_from_the_drones_cache_without_acting_twice() -> None:
    # GIVEN a link that loses the drone's first COMMAND_ACK
    link = LossyLink()
    lost: list[Any] = []

    def lose_first_ack(msg: Any) -> bool:
        if msg.get_type() == "COMMAND_ACK" and not lost:
            lost.append(msg)
            return True
        return False

    link.lose_down = lose_first_ack
    # WHEN the ground station arms the drone
    ack, _ = run_command(link, CommandClient(), ARM, (1.0,))
    # THEN the retry is answered ACCEPTED and the vehicle still saw one arm request
    assert ack == Ack(SYSID, ACCEPTED) and len(lost) == 1
    assert [m.confirmation for m in link.sent_up] == [0, 1]
    assert link.vehicle.requests == [Arm(force=False)]


def test_a_drone_that_never_hears_gets_every_retry_then_the_command_ends_with_no_answer() -> None:
    link = LossyLink()
    link.lose_up = lambda _msg: True
    ack, at_s = run_command(link, CommandClient(), ARM, (1.0,))
    assert ack == Ack(SYSID, None)
    assert [m.confirmation for m in link.sent_up] == [0, 1, 2, 3]
    assert at_s == 4 * COMMAND_TIMEOUT_S and link.vehicle.requests == []


def set_param(link: LossyLink, client: ParamClient, name: str, value: float) -> Any:
    """Start a set at t=0 and serve it as the swarm does until it ends; its outcome."""
    now = 0.0
    inbox = link.exchange(client.start(SYSID, name, value, now), now)
    while True:
        effects: list[Send] = []
        for msg in inbox:
            effects += client.handle(msg, now)  # a resend at once after an echo of another value
        if (result := client.take(SYSID, name)) is not None:
            return result
        if not effects:
            now = client.next_due_s()
            effects = client.poll(now)
        inbox = link.exchange(effects, now)


def test_a_parameter_set_is_confirmed_by_the_drones_echo() -> None:
    link = LossyLink()
    result = set_param(link, ParamClient(), "MIS_TAKEOFF_ALT", 4.0)
    assert result.ok and result.kept == 4.0
    assert len([m for m in link.sent_up if m.get_type() == "PARAM_SET"]) == 1


def test_a_value_out_of_range_is_refused_after_the_retries_and_the_kept_value_is_reported() -> None:
    # GIVEN a parameter whose range ends at 100  WHEN 500 is set
    link = LossyLink()
    result = set_param(link, ParamClient(), "MIS_TAKEOFF_ALT", 500.0)
    # THEN every echo carries the kept 2.5; after the retries the set is refused with it
    assert result.refused and result.kept == 2.5
    assert len([m for m in link.sent_up if m.get_type() == "PARAM_SET"]) == 1 + PARAM_RETRIES
