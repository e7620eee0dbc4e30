"""Flight dynamics: the Plant interface and its JSBSim implementation."""
