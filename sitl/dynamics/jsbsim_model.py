"""Generate the JSBSim aircraft definition of a multirotor from its airframe data file.

The flight model must never disagree with the controller about the vehicle, so nothing here is typed by hand:
every mass, length, coefficient and time constant comes from ``sitl.dynamics.airframe.Airframe`` and is converted from
SI to JSBSim's units either through JSBSim's own ``unit`` attributes or, where a property is fixed in English
units (external force magnitudes are pounds, moments pound-feet, velocities feet per second), through the
explicit factors below.

What the generated model contains:

- Mass and diagonal inertia, centre of gravity at the structural origin.
- One ``STRUCTURE`` ground contact below each rotor at the gear height, spring and damping from the
  airframe and isotropic Coulomb friction (JSBSim resolves static friction exactly, so a landed vehicle does
  not creep), plus one at each motor so a vehicle that tips over rests on its arms.
- A ``motors`` system: per rotor, the normalised command ``fcs/motor-cmd-norm[i]`` in [0, 1] is scaled to a
  rotor-speed command (0 to the maximum rotor speed) and passed through a first-order lag (the motor time
  constant) to give ``fcs/rotor-speed-radps[i]``. There is no other flight control: the Python cascade is
  the only controller.
- External reactions: each rotor's thrust ``k_t * omega^2`` along body -z at the rotor position (so roll
  and pitch moments come from the geometry), the summed rotor drag torque ``spin_dir * k_q * omega^2`` about
  body z, and quadratic airframe drag ``-c * v * |v|`` per body axis against the air-relative velocity, so
  wind pushes the vehicle.

Gravity, the standard atmosphere and the rotating WGS84 Earth are JSBSim's defaults.

Frames: JSBSim locations are in its structural frame (x aft, y right, z up); force and moment directions with
``frame="BODY"`` are in the body frame, which is FRD like ours. Hence a rotor at FRD (x, y, z) sits at
structural (-x, y, -z).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from sitl.dynamics.airframe import Airframe

# Exact unit definitions (international foot and pound-force).
M_PER_FT = 0.3048
N_PER_LBF = 4.4482216152605
LBF_PER_N = 1.0 / N_PER_LBF
LBFFT_PER_NM = LBF_PER_N / M_PER_FT

# Skid-on-ground friction: generic values for plastic skids on grass or concrete, not airframe properties.
GROUND_STATIC_FRICTION = 1.0
GROUND_DYNAMIC_FRICTION = 0.8

MOTOR_CMD_PROPERTY = "fcs/motor-cmd-norm[{index}]"
ROTOR_SPEED_CMD_PROPERTY = "fcs/rotor-speed-cmd-radps[{index}]"
ROTOR_SPEED_PROPERTY = "fcs/rotor-speed-radps[{index}]"
MOTOR_LAG_BLEND_PROPERTY = "fcs/motor-lag-blend"
# JSBSim binds STRUCTURE contacts under contact/unit[i] (BOGEY wheels would be gear/unit[i]).
CONTACT_WOW_PROPERTY = "contact/unit[{index}]/WOW"


def motor_cmd_property(index: int) -> str:
    return MOTOR_CMD_PROPERTY.format(index=index)


def rotor_speed_property(index: int) -> str:
    return ROTOR_SPEED_PROPERTY.format(index=index)


def contact_wow_property(index: int) -> str:
    return CONTACT_WOW_PROPERTY.format(index=index)


def contact_count(airframe: Airframe) -> int:
    """Ground contacts in the model: a skid below every rotor, then every motor itself."""
    return 2 * len(airframe.rotors)


def model_name(airframe: Airframe) -> str:
    """The JSBSim model name: the airframe name reduced to characters that are safe in a directory name."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", airframe.name)


def _num(value: float) -> str:
    # repr keeps every digit, so the model is exactly the airframe file.
    return repr(float(value))


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    element = ET.SubElement(parent, tag, attrib)
    if text is not None:
        element.text = text
    return element


def _triplet(parent: ET.Element, tag: str, xyz: tuple[float, float, float], **attrib: str) -> ET.Element:
    element = _sub(parent, tag, **attrib)
    for axis, value in zip(("x", "y", "z"), xyz, strict=True):
        _sub(element, axis, _num(value))
    return element


def _structural_m(pos_frd_m: tuple[float, float, float]) -> tuple[float, float, float]:
    x, y, z = pos_frd_m
    return (-x, y, -z)


def _square_term(parent: ET.Element, gain: float, prop: str) -> None:
    product = _sub(parent, "product")
    _sub(product, "value", _num(gain))
    _sub(product, "property", prop)
    _sub(product, "property", prop)


def _metrics(root: ET.Element, airframe: Airframe) -> None:
    metrics = _sub(root, "metrics")
    # Reference area and lengths only scale JSBSim's coefficient-based aerodynamics, which this model does not
    # use (drag is an external force); they must still be positive to keep derived aero properties finite.
    span_m = 2.0 * airframe.collision_radius_m
    _sub(metrics, "wingarea", _num(span_m * span_m), unit="M2")
    _sub(metrics, "wingspan", _num(span_m), unit="M")
    _sub(metrics, "chord", _num(span_m), unit="M")
    for name in ("AERORP", "EYEPOINT", "VRP"):
        _triplet(metrics, "location", (0.0, 0.0, 0.0), name=name, unit="M")


def _mass_balance(root: ET.Element, airframe: Airframe) -> None:
    mass = _sub(root, "mass_balance")
    ixx, iyy, izz = airframe.inertia_diag_kg_m2
    for tag, value in (("ixx", ixx), ("iyy", iyy), ("izz", izz), ("ixy", 0.0), ("ixz", 0.0), ("iyz", 0.0)):
        _sub(mass, tag, _num(value), unit="KG*M2")
    _sub(mass, "emptywt", _num(airframe.mass_kg), unit="KG")
    _triplet(mass, "location", (0.0, 0.0, 0.0), name="CG", unit="M")


def _contact(ground: ET.Element, name: str, pos_frd_m: tuple[float, float, float], airframe: Airframe) -> None:
    contact = _sub(ground, "contact", type="STRUCTURE", name=name)
    _triplet(contact, "location", _structural_m(pos_frd_m), unit="M")
    _sub(contact, "static_friction", _num(GROUND_STATIC_FRICTION))
    _sub(contact, "dynamic_friction", _num(GROUND_DYNAMIC_FRICTION))
    _sub(contact, "spring_coeff", _num(airframe.gear_spring_n_per_m), unit="N/M")
    _sub(contact, "damping_coeff", _num(airframe.gear_damping_n_per_mps), unit="N/M/SEC")


def _ground_reactions(root: ET.Element, airframe: Airframe) -> None:
    ground = _sub(root, "ground_reactions")
    for i, rotor in enumerate(airframe.rotors):
        x, y, _ = rotor.pos_frd_m
        _contact(ground, f"skid-{i}", (x, y, airframe.gear_height_m), airframe)
    # The motors are the other hard points: a vehicle that tips over or lands inverted rests on them instead
    # of sinking its centre of gravity into the ground.
    for i, rotor in enumerate(airframe.rotors):
        _contact(ground, f"motor-{i}", rotor.pos_frd_m, airframe)


def _motors_system(root: ET.Element, airframe: Airframe) -> None:
    system = _sub(root, "system", name="motors")
    for i in range(len(airframe.rotors)):
        _sub(system, "property", motor_cmd_property(i), value="0")
        _sub(system, "property", rotor_speed_property(i), value="0")
    # Exact discretisation of d(omega)/dt = (omega_cmd - omega) / tau over one step of length dt:
    # omega += (1 - exp(-dt / tau)) * (omega_cmd - omega). It reaches 63.2 % of a step in one time constant
    # whatever the step, and its state is the rotor-speed property itself, so a plant can start with the
    # rotors spinning by writing that property (JSBSim's lag_filter restarts from zero on run_ic). While
    # JSBSim initialises, simulation/dt is 0 and the speed does not move.
    lag = _sub(_sub(system, "channel", name="motor-lag"), "fcs_function", name="motor-lag-blend")
    blend = _sub(_sub(lag, "function"), "difference")
    _sub(blend, "value", "1")
    exponent = _sub(_sub(blend, "exp"), "product")
    _sub(exponent, "value", _num(-1.0 / airframe.motor_time_constant_s))
    _sub(exponent, "property", "simulation/dt")
    _sub(lag, "output", MOTOR_LAG_BLEND_PROPERTY)
    max_speed = airframe.motor_max_speed_radps
    for i in range(len(airframe.rotors)):
        channel = _sub(system, "channel", name=f"motor-{i}")
        command = _sub(channel, "pure_gain", name=f"motor-{i}-speed-command")
        _sub(command, "input", motor_cmd_property(i))
        _sub(command, "gain", _num(max_speed))
        clip = _sub(command, "clipto")
        _sub(clip, "min", "0")
        _sub(clip, "max", _num(max_speed))
        _sub(command, "output", ROTOR_SPEED_CMD_PROPERTY.format(index=i))
        speed = _sub(channel, "fcs_function", name=f"motor-{i}-speed")
        total = _sub(_sub(speed, "function"), "sum")
        _sub(total, "property", rotor_speed_property(i))
        step = _sub(total, "product")
        _sub(step, "property", MOTOR_LAG_BLEND_PROPERTY)
        error = _sub(step, "difference")
        _sub(error, "property", ROTOR_SPEED_CMD_PROPERTY.format(index=i))
        _sub(error, "property", rotor_speed_property(i))
        _sub(speed, "output", rotor_speed_property(i))


def _external_reactions(root: ET.Element, airframe: Airframe) -> None:
    reactions = _sub(root, "external_reactions")
    thrust_lbf_per_radps2 = airframe.thrust_coeff_n_per_radps2 * LBF_PER_N
    for i, rotor in enumerate(airframe.rotors):
        force = _sub(reactions, "force", name=f"rotor-{i}-thrust", frame="BODY")
        _square_term(_sub(force, "function"), thrust_lbf_per_radps2, rotor_speed_property(i))
        _triplet(force, "location", _structural_m(rotor.pos_frd_m), unit="M")
        _triplet(force, "direction", (0.0, 0.0, -1.0))

    # Rotor drag torque reacts on the body about its z axis with the sign of the spin direction.
    torque = _sub(reactions, "moment", name="rotor-drag-torque", frame="BODY")
    total = _sub(_sub(torque, "function"), "sum")
    torque_lbfft_per_radps2 = airframe.torque_coeff_nm_per_radps2 * LBFFT_PER_NM
    for i, rotor in enumerate(airframe.rotors):
        _square_term(total, rotor.spin_dir * torque_lbfft_per_radps2, rotor_speed_property(i))
    _triplet(torque, "direction", (0.0, 0.0, 1.0))

    # F = -c v|v| with v in m/s and F in N, written for v in ft/s and F in lbf.
    axes = (("x", "u", (1.0, 0.0, 0.0)), ("y", "v", (0.0, 1.0, 0.0)), ("z", "w", (0.0, 0.0, 1.0)))
    for (axis, component, direction), coeff in zip(axes, airframe.drag_coeff_frd_n_per_mps2, strict=True):
        drag = _sub(reactions, "force", name=f"drag-{axis}", frame="BODY")
        product = _sub(_sub(drag, "function"), "product")
        _sub(product, "value", _num(-coeff * M_PER_FT * M_PER_FT * LBF_PER_N))
        _sub(product, "property", f"velocities/{component}-aero-fps")
        _sub(_sub(product, "abs"), "property", f"velocities/{component}-aero-fps")
        _triplet(drag, "location", (0.0, 0.0, 0.0), unit="M")
        _triplet(drag, "direction", direction)


def model_xml(airframe: Airframe) -> str:
    """The JSBSim ``fdm_config`` document for an airframe, as text."""
    root = ET.Element("fdm_config", name=model_name(airframe), version="2.0", release="BETA")
    header = _sub(root, "fileheader")
    _sub(header, "description", f"Multirotor generated from {airframe.source_path.name}; do not edit.")
    _metrics(root, airframe)
    _mass_balance(root, airframe)
    _ground_reactions(root, airframe)
    _sub(root, "propulsion")
    _motors_system(root, airframe)
    _sub(root, "flight_control", name="pass-through")
    _sub(root, "aerodynamics")
    _external_reactions(root, airframe)
    ET.indent(root)
    return '<?xml version="1.0"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def write_model(airframe: Airframe, root_dir: Path) -> Path:
    """Write the model in JSBSim's layout, ``<root_dir>/aircraft/<name>/<name>.xml``, and return that path."""
    name = model_name(airframe)
    path = Path(root_dir) / "aircraft" / name / f"{name}.xml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(model_xml(airframe), encoding="utf-8")
    return path
