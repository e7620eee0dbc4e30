"""The compiled kernels (sitl/kernels): the rules sitl/kernels/__init__.py states, each checked.

- the helpers that make a kernel give Python's bits: CPython's ``math.hypot`` and ``x ** 2``, numpy's ``sum``;
- every kernel is compiled when its module is imported (explicit signatures), so a forked drone never compiles;
- processes compiling at once into an empty cache all succeed and fly the same, and the next process only loads;
- ``SWARM_KERNELS=python`` runs the kernels as Python, and a takeoff flies the same bits both ways;
- no numpy transcendental function in flight code: the drone's (all of sitl/) and the ground station's flight laws
  (gcs/ but its live view), where only ``np.sin`` and ``np.cos`` are allowed (numpy computes them with the C
  library's code for float64; its arctan2, arcsin, exp... are SIMD code that rounds differently by CPU).
"""

from __future__ import annotations

import ast
import importlib
import json
import math
import os
import pkgutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sitl.kernels
from sitl.kernels.pymath import hypot2, hypot3, np_sum, py_square

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
NUMPY_TRANSCENDENTALS = frozenset({
    "sin", "cos", "tan", "arcsin", "arccos", "arctan", "arctan2", "sinh", "cosh", "tanh", "arcsinh", "arccosh",
    "arctanh", "exp", "exp2", "expm1", "log", "log2", "log10", "log1p", "power", "float_power", "hypot", "cbrt",
})  # fmt: skip
STABLE_IN_NUMPY = frozenset({"sin", "cos"})


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="CPython 3.12 computes math.hypot with fma")
def test_hypot_is_cpythons_to_the_last_bit_at_every_scale() -> None:
    rng = np.random.default_rng(7)
    specials = [
        (0.0, 0.0, 0.0),
        (-0.0, 3.0, 4.0),
        (math.inf, math.nan, 1.0),
        (math.nan, 1.0, 2.0),
        (5e-324, 0.0, 1e-310),
    ]
    for scale in (1e-310, 1e-150, 1e-3, 1.0, 1e4, 1e150, 1e300):
        rows = rng.standard_normal((20000, 3)) * scale * np.exp(rng.uniform(-4.0, 4.0, (20000, 3)))
        for x, y, z in [*rows.tolist(), *specials]:
            for got, want in ((hypot2(x, y), math.hypot(x, y)), (hypot3(x, y, z), math.hypot(x, y, z))):
                assert got == want or (math.isnan(got) and math.isnan(want)), (x, y, z, got, want)


def test_py_square_is_cpythons_power_of_two_not_a_product() -> None:
    rng = np.random.default_rng(9)
    values = (rng.standard_normal(100_000) * np.exp(rng.uniform(-20.0, 20.0, 100_000))).tolist()
    assert all(py_square(x) == x**2 for x in values)
    # and x ** 2 is not always x * x in CPython (the C library's pow): otherwise py_square would be needless
    assert any(x**2 != x * x for x in values)


def test_np_sum_adds_up_as_numpy_does() -> None:
    rng = np.random.default_rng(8)
    for n in [*range(0, 300), 511, 1000, 4099]:
        values = rng.standard_normal(n) * np.exp(rng.uniform(-8.0, 8.0, n))
        assert np_sum(values) == float(values.sum()), n


def _kernel_modules() -> list[str]:
    return [f"sitl.kernels.{m.name}" for m in pkgutil.iter_modules(sitl.kernels.__path__)]


@pytest.mark.skipif(not sitl.kernels.compiled(), reason="kernels switched off in this process")
def test_every_kernel_is_compiled_when_its_module_is_imported_and_never_again() -> None:
    import numba.core.registry

    found = 0
    for name in _kernel_modules():
        module = importlib.import_module(name)
        for value in vars(module).values():
            if isinstance(value, numba.core.registry.CPUDispatcher) and value.__module__ == name:
                found += 1
                assert value.signatures, f"{name}.{value.__name__} has no compiled signature"
                assert not value._can_compile, f"{name}.{value.__name__} would compile on a new argument type"
    assert found >= 10


_FLY = """
import hashlib, json, sys
import numba.core.registry
import sitl.process.app, sitl.perception.detector  # every drone module, as the zygote imports them before it forks
from sitl.kernels import compiled
from tests.closed_loop.flight import arm_when_ready, make_sim
sim = make_sim(seed=4)
arm_when_ready(sim)
assert sim.vehicle.takeoff(2.0).ok
digest = hashlib.sha256()
for _ in range(750):
    digest.update(sim.step().pos_ned_m.tobytes())
stats = {"hits": 0, "misses": 0}
for module in [m for name, m in list(sys.modules.items()) if name.startswith("sitl.kernels.")]:
    for value in vars(module).values():
        if isinstance(value, numba.core.registry.CPUDispatcher):
            stats["hits"] += sum(value.stats.cache_hits.values())
            stats["misses"] += sum(value.stats.cache_misses.values())
print(json.dumps({"digest": digest.hexdigest(), "compiled": compiled(), **stats}))
"""


def _start(env: dict[str, str]) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", _FLY], cwd=ROOT, env={**os.environ, **env}, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)  # fmt: skip


def _result(proc: subprocess.Popen[str]) -> dict[str, object]:
    out, err = proc.communicate(timeout=100)
    assert proc.returncode == 0, err[-3000:]
    return dict(json.loads(out.strip().splitlines()[-1]))


@pytest.mark.acceptance  # three cold compiles into a cache of its own, about 50 s on two cores: the suite has no room
def test_processes_compiling_at_once_into_an_empty_cache_fly_alike_and_the_next_only_loads(tmp_path: Path) -> None:
    env = {"NUMBA_CACHE_DIR": str(tmp_path / "cache"), "SWARM_KERNELS": "", "NUMBA_DISABLE_JIT": "0"}
    first, second = _start(env), _start(env)  # a sweep's two jobs on a cold cache
    a, b = _result(first), _result(second)
    assert a["compiled"] and b["compiled"]
    assert a["misses"] and b["misses"]  # both compiled: the cache was empty
    assert a["digest"] == b["digest"]
    third = _result(_start(env))
    assert third["hits"] and not third["misses"], third
    assert third["digest"] == a["digest"]
    uncompiled = _result(_start({"SWARM_KERNELS": "python"}))
    assert uncompiled["compiled"] is False and not uncompiled["hits"] and not uncompiled["misses"]
    assert uncompiled["digest"] == a["digest"]  # the kernels are written to give their Python form's bits


def _banned_calls(path: Path, allowed: frozenset[str]) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    return [
        f"{path.relative_to(ROOT)}:{node.lineno}: np.{node.attr}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and isinstance(node.value, ast.Name)
        and node.value.id in ("np", "numpy")
        and node.attr in NUMPY_TRANSCENDENTALS - allowed
    ]


def test_no_numpy_transcendental_in_flight_code() -> None:
    found = [hit for path in sorted((ROOT / "sitl").rglob("*.py")) for hit in _banned_calls(path, frozenset())]
    found += [
        hit
        for path in sorted((ROOT / "gcs").rglob("*.py"))
        if "view" not in path.relative_to(ROOT / "gcs").parts
        for hit in _banned_calls(path, STABLE_IN_NUMPY)
    ]
    assert not found, "numpy's SIMD transcendentals round differently by CPU; use math (or a kernel):\n" + "\n".join(
        found
    )


@pytest.mark.skipif(not sitl.kernels.compiled(), reason="kernels switched off in this process")
def test_the_compiled_cascade_gives_its_python_forms_bits_saturated_or_not() -> None:
    from sitl.control.cascade import Cascade
    from sitl.drone.param_table import build_param_store
    from sitl.dynamics.airframe import load_airframe
    from sitl.kernels import cascade as ck

    cascade = Cascade(load_airframe(), build_param_store())
    rng = np.random.default_rng(11)
    rows, t_max = cascade.allocator.rows, cascade.allocator.thrust_max_n
    saturated = 0
    for _ in range(3000):
        q = rng.standard_normal(4)
        q /= math.sqrt(float((q * q).sum()))
        d = rng.standard_normal(4)
        d /= math.sqrt(float((d * d).sum()))
        ff = float(rng.choice([math.nan, rng.standard_normal()]))
        args = (*q.tolist(), *d.tolist(), ff, cascade.attitude.row)
        assert ck.attitude_rates(*args) == ck.attitude_rates.py_func(*args)
        rates = (rng.standard_normal(6) * 2.0).tolist()
        states = [np.array(rng.standard_normal(ck.RATE_STATE_SIZE).clip(0.0, None)) for _ in range(2)]
        states[1][:] = states[0]
        step = (*rates, 0.004, bool(rng.integers(0, 2)))
        assert ck.rate_torque(states[0], cascade.rate.row, *step) == ck.rate_torque.py_func(
            states[1], cascade.rate.row, *step
        )
        assert np.array_equal(states[0], states[1])
        demand = (
            *(rng.standard_normal(3) * (0.1, 0.1, 0.02) * rng.choice([1.0, 10.0])).tolist(),
            float(rng.uniform(-5.0, 60.0)),
        )
        outs = [(np.empty(len(rows)), np.empty(len(rows)), np.empty(ck.FLAGS_SIZE)) for _ in range(2)]
        ck.allocate(rows, t_max, *demand, *outs[0])
        ck.allocate.py_func(rows, t_max, *demand, *outs[1])
        assert all(np.array_equal(a, b) for a, b in zip(*outs, strict=True))
        saturated += bool(outs[0][2].any())
        velocity = [np.array(rng.standard_normal(ck.VELOCITY_STATE_SIZE)) for _ in range(2)]
        velocity[1][:] = velocity[0]
        vel = [x if rng.random() > 0.2 else math.nan for x in (rng.standard_normal(9) * 3.0).tolist()]
        got = ck.velocity_thrust(velocity[0], cascade.velocity.row, *vel, 0.01, False)
        want = ck.velocity_thrust.py_func(velocity[1], cascade.velocity.row, *vel, 0.01, False)
        assert np.array_equal(np.array(got), np.array(want), equal_nan=True) and np.array_equal(
            *velocity, equal_nan=True
        )
    assert saturated > 300  # the priority path was exercised, not only the common one


def test_a_cache_compiled_from_other_kernel_sources_is_dropped_whole_and_a_current_one_is_kept(tmp_path: Path) -> None:
    # GIVEN a cache directory holding compiled kernels and no record of the sources they came from
    from sitl.kernels import FINGERPRINT_FILE, drop_stale_cache, sources_fingerprint

    cache = tmp_path / "__pycache__"
    cache.mkdir()
    compiled = [cache / "frame.camera_pass-41.py311.nbi", cache / "frame.camera_pass-41.py311.1.nbc"]
    for path in compiled:
        path.write_bytes(b"machine code")
    current = sources_fingerprint()
    # WHEN it is checked against the current sources THEN every compiled kernel is dropped and the sources recorded
    assert drop_stale_cache(cache, current)
    assert not any(path.exists() for path in compiled)
    assert (cache / FINGERPRINT_FILE).read_text() == current
    # AND kernels compiled since are kept while the sources stay the same
    for path in compiled:
        path.write_bytes(b"machine code")
    assert not drop_stale_cache(cache, current)
    assert all(path.exists() for path in compiled)
    # AND dropped again once any kernel module's source differs (a callee's change reaches its callers)
    assert drop_stale_cache(cache, "another source")
    assert not any(path.exists() for path in compiled)
    # AND the fingerprint is one of every kernel module's source
    assert current == sources_fingerprint() and len(current) == 64
