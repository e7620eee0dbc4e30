"""The PX4-style multicopter controller cascade, as small pure stages.

position (P) -> velocity (PID, m/s^2) -> thrust vector (N, NED) -> attitude (quaternion P) -> body rates (PID,
N m) -> control allocation (motor commands from the airframe geometry). Each stage is a plain class with
``update(...)`` and ``reset()`` holding a frozen config; none of them reads the parameter store, a clock or a
socket. ``cascade.Cascade`` composes them and owns the parameter -> config refresh.

Vectors travel between stages as tuples of Python floats: the stages do a few dozen multiplications per step,
and at that size plain float arithmetic is several times faster than numpy (the cascade runs 400 times a
second for every drone of the swarm).
"""

Vec3f = tuple[float, float, float]
