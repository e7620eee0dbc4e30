"""One simulated drone: JSBSim flight model, sensors, PX4-style autopilot and MAVLink endpoint."""
