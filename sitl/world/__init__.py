"""What drones share: the shared world of bodies, a drone's view of it, lockstep, the mesh and the link model."""
