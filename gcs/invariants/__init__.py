"""Properties of a flight, declared once and checked by the supervisor at every tick (docs/invariants.md).

``spec``: what an invariant says (a property of one instant and a form: always, or eventually within a time after
each event of a kind), read from plain fields as a mission's ``[[invariants]]`` gives them. ``state``: the instant
the supervisor checks them on, built from what it knows (telemetry; the simulation's own reports of contacts).
``monitor``: the check itself, pure, the first violation of each invariant kept with its time, the drones involved
and the values.
"""
