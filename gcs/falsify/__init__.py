"""Falsification: searching a mission's space of conditions and perturbations for a flight that breaks one of its
invariants (docs/falsify.md). ``space``: the space, read from a mission's ``[falsify]`` table, and each point of it
written back as a plain mission file."""
