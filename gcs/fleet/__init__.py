"""The swarm link: the running swarm (spawn, telemetry, liveness, shutdown), its fleet view, the relay, and what the
ground station needs from a simulation."""
