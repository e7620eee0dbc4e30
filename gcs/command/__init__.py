"""Commanding the fleet over MAVLink: setpoint streaming, takeoff and landing procedures, the loss policy, onboard
hand-over."""
