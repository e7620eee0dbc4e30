"""What both sides must read alike, written once: the user-facing settings and rules the ground station (gcs) and
the drones (sitl) share. It imports neither, and neither side reaches the other through it (import-linter
contracts in pyproject.toml).

What checks the other side stays apart on purpose and is not here: the wire decoding, geodesy, PX4's modes and the
signing key-file reader are written twice, so that an encoding bug cannot cancel out in the tests
(docs/architecture.md, "Shared rules")."""
