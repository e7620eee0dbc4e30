"""The one error the swarm's parts raise for what the swarm cannot do (gcs/fleet/swarm.py and the parts it is made
of), defined below all of them so that none imports the facade for it."""

from __future__ import annotations


class SwarmError(RuntimeError):
    """A swarm-level operation failed; the message is one line for the user."""
