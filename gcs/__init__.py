"""The ground station: spawns drones, flies formations, relays neighbour positions."""
