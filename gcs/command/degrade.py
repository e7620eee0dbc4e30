"""What the survivors do when the swarm loses a drone: the loss policy carried out over MAVLink.

``continue`` re-plans what is being flown over the survivors (gcs/command/streamer.py ``handle_loss``: a formation
re-forms with one synchronised, collision-aware transition; a lost leader hands over; flocking goes on); ``hold``
puts every survivor in PX4 Hold where it is, ``land`` lands them where they are and ``abort`` returns them to
launch, where they land (PX4 Return). Used by ``swarm up`` (gcs/supervisor/station.py) and ``swarm fly``
(gcs/supervisor/mission_runner.py) alike.

A drone lost for silence can come back (its link did): ``apply_regain`` takes it in again under ``continue`` and has
it do what the survivors were told under the other policies.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

from gcs.command.streamer import FormationStreamer
from gcs.fleet.commanding import HOLD_MODE, check
from gcs.fleet.errors import SwarmError
from gcs.fleet.losses import DroneLoss, LossPolicy


def apply_loss_policy(policy: LossPolicy, streamer: FormationStreamer, loss: DroneLoss, now_s: float) -> str | None:
    """Carry out ``policy`` after ``loss``; returns one line saying what the swarm does (None: nothing changed).
    A drone that refuses is named in the line rather than raised: the survivors' flight goes on either way."""
    swarm = streamer.swarm
    try:
        if policy is LossPolicy.CONTINUE:
            return streamer.handle_loss(loss.sysid, now_s)
        if policy is LossPolicy.HOLD:
            streamer.hand_over(swarm.commands.hold_all)
            return "loss policy hold: every drone holds where it is"
        if policy is LossPolicy.LAND:
            streamer.hand_over(swarm.commands.land_all)
            return "loss policy land: every drone lands where it is"
        streamer.hand_over(lambda: swarm.commands.land_all(return_to_launch=True))
        return "loss policy abort: every drone returns to launch and lands"
    except SwarmError as exc:
        return f"loss policy {policy.value}: {exc}"


def apply_regain(policy: LossPolicy, streamer: FormationStreamer, loss: DroneLoss, now_s: float, *,
                 policy_taken: bool) -> str | None:  # fmt: skip
    """A drone heard again after ``loss`` (a silent one): under ``continue``, or before any loss policy took the
    survivors out of the flight, what is flown takes it back (``FormationStreamer.handle_regain``); once ``hold``,
    ``land`` or ``abort`` has acted (``policy_taken``), the drone is told the same as the survivors were. Returns
    one line saying what the swarm does (None: nothing changed)."""
    swarm = streamer.swarm
    try:
        if policy is LossPolicy.CONTINUE or not policy_taken:
            return streamer.handle_regain(loss.sysid, now_s)
        if loss.sysid not in swarm.liveness.armed_sysids([loss.sysid]):
            return f"sysid {loss.sysid} is on the ground: it stays there"
        if policy is LossPolicy.HOLD:
            check(swarm.commands.command_all(mavlink.MAV_CMD_DO_SET_MODE, *HOLD_MODE, sysids=[loss.sysid]), "hold")
            return f"loss policy hold: sysid {loss.sysid} holds where it is too"
        if policy is LossPolicy.LAND:
            swarm.commands.land_all()
            return f"loss policy land: sysid {loss.sysid} lands too"
        swarm.commands.land_all(return_to_launch=True)
        return f"loss policy abort: sysid {loss.sysid} returns to launch too"
    except SwarmError as exc:
        return f"loss policy {policy.value}: {exc}"
