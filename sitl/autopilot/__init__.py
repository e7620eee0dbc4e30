"""The autopilot's parts: one unit per flight mode (modes.py), the failsafe table (failsafe.py) and the typed
phases the units move through (phases.py). sitl/autopilot/commander.py wires them to the estimate and the controller
cascade."""
