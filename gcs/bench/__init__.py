"""``swarm bench``: how the swarm scales on this machine, and the relay-latency probe."""
