"""What the swarm flies, as pure laws: geodesy and frames, formations and their transitions, assignment, flocking,
leader-follower, crossing moves."""
