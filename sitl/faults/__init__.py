"""Injected failures (PX4's MAV_CMD_INJECT_FAILURE) and their parameters."""
