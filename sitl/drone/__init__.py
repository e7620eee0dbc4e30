"""One drone without IO: the closed loop (plant, sensors, estimator, autopilot), the autopilot as the MAVLink services
see it (``sim_vehicle_api``), awareness (cameras and relayed neighbours), the demo flight, the parameter reference."""
