"""A drone process: its entry (app), run loop and pacing, the hosted drones with their MAVLink IO, ports and specs."""
