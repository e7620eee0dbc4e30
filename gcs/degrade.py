"""What the survivors do when the swarm loses a drone: the loss policy carried out over MAVLink.

``continue`` re-plans what is being flown over the survivors (gcs/streamer.py ``handle_loss``: a formation
re-forms with one synchronised, collision-aware transition; a lost leader hands over; flocking goes on); ``hold``
puts every survivor in PX4 Hold where it is, ``land`` lands them where they are and ``abort`` returns them to
launch, where they land (PX4 Return). Used by ``swarm up`` (gcs/station.py) and ``swarm fly``
(gcs/mission_runner.py) alike.
"""

from __future__ import annotations

from gcs.losses import DroneLoss, LossPolicy
from gcs.streamer import FormationStreamer
from gcs.swarm import SwarmError


def apply_loss_policy(policy: LossPolicy, streamer: FormationStreamer, loss: DroneLoss, now_s: float) -> str | None:
    """Carry out ``policy`` after ``loss``; returns one line saying what the swarm does (None: nothing changed).
    A drone that refuses is named in the line rather than raised: the survivors' flight goes on either way."""
    swarm = streamer.swarm
    try:
        if policy is LossPolicy.CONTINUE:
            return streamer.handle_loss(loss.sysid, now_s)
        streamer.stop()
        if policy is LossPolicy.HOLD:
            swarm.hold_all()
            return "loss policy hold: every drone holds where it is"
        if policy is LossPolicy.LAND:
            swarm.land_all()
            return "loss policy land: every drone lands where it is"
        swarm.land_all(return_to_launch=True)
        return "loss policy abort: every drone returns to launch and lands"
    except SwarmError as exc:
        return f"loss policy {policy.value}: {exc}"
