"""Distributed swarm laws written as onboard behaviours: each drone runs one from its own estimate and its neighbour
table alone, with no ground station in the loop (docs/onboard.md, "Shipped behaviours").

``flocking.Flocking`` and ``leader_follower.LeaderFollower`` fly the same laws as the ground station's flocking and
leader-follower (gcs/flight/behaviours.py), one drone's view at a time. Load them like any behaviour, by module:
``sitl.onboard.behaviours.flocking:Flocking``; a mission's ``flock`` or ``follow`` step with ``onboard = true``
does it, sets their parameters and starts them. ``points`` holds what both need: a short list of points in
MAVLink parameters, and 2-D vector helpers.
"""
