"""One drone without IO: the closed loop (plant, sensors, estimator, autopilot), its MAVLink-facing vehicle API,
awareness, the demo flight."""
