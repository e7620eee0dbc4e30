"""Collision avoidance: the algorithm (fusion, velocity obstacles) and collision prevention in the autopilot."""
