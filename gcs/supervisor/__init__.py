"""The supervisor: one flight session (``session``), the swarm's verbs written once (``verbs``), and the front-ends
that drive them: ``swarm up``'s station and its control channel, ``swarm fly``'s mission runner, ``swarm plan``."""
