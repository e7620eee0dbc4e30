"""The supervisor's front-ends: ``swarm up``'s station and control channel, ``swarm fly``'s mission runner."""
