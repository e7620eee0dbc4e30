"""The swarm link: the running swarm as a facade (``swarm``) over its parts: the clock (``clock``), the router
(``router``: traffic both ways, batching, forwarding, the relay), liveness (``liveness``), the fleet view from
telemetry (``telemetry``); and the settings it is launched with (links, faults, loss records) and what the ground
station needs from a simulation (``harness``)."""
