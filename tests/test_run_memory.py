"""What a run stores, and runs that would take all memory (reliability items 0 and 8).

- A long simulation keeps only what it is asked for (``t_eval``): as many samples for 2000
  periods of an oscillator as for 20, and the final state of the closed form.
- A record that outgrows the memory the process may take (``RLIMIT_AS`` in a child
  process) is refused by a ValueError that names the record, not a MemoryError blamed on
  the model, and not a kill.
- The flow map of a pronking body on four legs with leg-extension coordinates (d = 12),
  its field written with ``np.zeros(d)`` (so ``J`` by central differences) and no event
  Jacobian: its variational stretch in the all-feet region shrank its steps to 1e-9 under
  the rounding of those differences (a pitch at 1e-31 took a step of 2^-37) and grew until
  the memory was gone. Now it ends, in bounded memory, with the flow map of finite
  differences of an independent solve_ivp simulation (its own event logic, written here).
"""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest
from scipy.integrate import solve_ivp

import bderiv
from bderiv.analysis.system import HybridSystem

_SRC = str(pathlib.Path(bderiv.__file__).resolve().parents[1])
_TESTS = str(pathlib.Path(__file__).resolve().parent)
linux = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_AS, /proc")


def _child(script, timeout):
    """Run ``script`` in a fresh Python (this bderiv, this directory importable)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([_SRC, _TESTS]))
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script)], env=env,
                          capture_output=True, text=True, timeout=timeout)


# -- the oscillator: x'' = -x, its contact surface x = 2 never reached --------------------

def rotate(x, mask):
    out = np.empty_like(x)
    out[0], out[1] = x[1], -x[0]
    return out


def far_wall(x):
    return np.array([x[0] - 2.0])


compiled_rotate, compiled_far_wall = numba.njit(rotate), numba.njit(far_wall)


def rotate_pairs(x, mask):
    """64 copies of :func:`rotate` side by side (d = 128): each step's record is wider, so
    a Python run reaches a memory limit in a tenth of the steps (and CPU) of d = 2."""
    out = np.empty_like(x)
    out[0::2], out[1::2] = x[1::2], -x[0::2]
    return out


@pytest.mark.parametrize("compiled", [True, False], ids=["compiled", "python"])
def test_a_long_simulation_keeps_only_the_samples_asked_for(compiled):
    """x(t) = (cos t, -sin t): 20 and 2000 periods (Python: 2 and 200) keep the 11
    samples of t_eval, each and the final state on the closed form; t_eval=() keeps none."""
    fns = (compiled_rotate, compiled_far_wall) if compiled else (rotate, far_wall)
    system = HybridSystem(*fns, n_events=1, dim=2)
    periods = (20, 2000) if compiled else (2, 200)
    for p in periods:
        T = 2 * np.pi * p + 0.5
        times = np.linspace(0.0, T, 11)
        traj = system.simulate([1.0, 0.0], T, t_eval=times)
        assert traj.t.shape == (11,) and traj.x.shape == (11, 2) and traj.masks.shape == (11,)
        np.testing.assert_array_equal(traj.t, times)
        closed = np.stack([np.cos(times), -np.sin(times)], axis=1)
        assert np.abs(traj.x - closed).max() < 1e-9 * p + 1e-9
        assert np.abs(traj.x_final - closed[-1]).max() < 1e-9 * p + 1e-9
        assert not traj.events and (traj.masks == 0).all()
        bare = system.simulate([1.0, 0.0], T, t_eval=())
        assert bare.t.size == 0 and bare.x.shape == (0, 2)
        np.testing.assert_array_equal(bare.x_final, traj.x_final)


def test_t_eval_across_events_takes_each_stretch_and_is_checked():
    """A unit-speed drift through two surfaces (x = 1 and x = 2, which slow it to 1/2 and
    1/4): the samples are on the closed form, masks of their regions; bad t_eval named."""

    @numba.njit
    def drift(x, mask):
        out = np.empty_like(x)
        out[0] = 1.0 / (1 + (mask & 1) + 2 * (mask >> 1 & 1))
        return out

    @numba.njit
    def walls(x):
        return np.array([x[0] - 1.0, x[0] - 2.0])

    system = HybridSystem(drift, walls, n_events=2, dim=1)
    times = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 4.0, 5.0])
    traj = system.simulate([0.0], 5.0, t_eval=times)
    # x = t to 1, then 1 + (t - 1) / 2 to 2 (t = 3), then 2 + (t - 3) / 4
    closed = np.where(times < 1, times, np.where(times < 3, 1 + (times - 1) / 2,
                                                 2 + (times - 3) / 4))
    assert np.abs(traj.x[:, 0] - closed).max() < 1e-10
    assert traj.masks.tolist() == [0, 0, 1, 1, 1, 3, 3, 3]
    for bad, words in [([1.0, 0.5], "ascending"), ([0.0, 6.0], "t_final"),
                       ([0.0, np.nan], "finite"), ([[0.0, 1.0]], "1-D")]:
        with pytest.raises(ValueError, match=words):
            system.simulate([0.0], 5.0, t_eval=bad)


# -- a record under a small address-space limit --------------------------------------------

_LIMITED = """
    import os, resource
    import numpy as np
    import test_run_memory as t
    from bderiv.analysis.system import HybridSystem
    compiled = {compiled}
    fns = (t.compiled_rotate, t.compiled_far_wall) if compiled else (t.rotate_pairs, t.far_wall)
    d = 2 if compiled else 128
    system = HybridSystem(*fns, n_events=1, dim=d)
    x0 = np.zeros(d)
    x0[0::2] = 1.0
    system.simulate(x0, 1.0)  # compiled (and loaded) without the limit
    with open("/proc/self/statm") as fh:
        used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    resource.setrlimit(resource.RLIMIT_AS, (used + ({room} << 20), resource.RLIM_INFINITY))
    try:
        system.simulate(x0, 1e9)
    except ValueError as exc:
        print("ValueError:", exc)
    except MemoryError as exc:
        print("MemoryError:", exc)
"""


@linux
@pytest.mark.parametrize("compiled,room", [(True, 300), (False, 120)],
                         ids=["compiled", "python"])
def test_a_record_that_outgrows_the_limit_is_refused_by_name(compiled, room):
    """simulate(x0, 1e9) keeps every step: with ``room`` MiB of address space left it is
    refused before the record takes them, naming the record and what to pass instead
    (Python: the oscillator at d = 128, :func:`rotate_pairs`)."""
    out = _child(_LIMITED.format(compiled=compiled, room=room), timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.startswith("ValueError:"), out.stdout
    message = out.stdout
    assert "record" in message and "RLIMIT_AS" in message
    assert "t_final" in message
    assert "compiled function of the model" not in message


# -- the pronking body on k legs with leg extensions (d = 4 + 2 k) ------------------------

G, APEX, LEG = 9.81, 0.66, 0.5


def pronking_body(k):
    """``field, events`` (Python functions) of the body on k legs, each with an extension
    coordinate: state ``(z, theta, s_1..s_k)`` and their rates; all feet land together
    from the apex. The field fills ``np.zeros(d)`` (float only: a compiled model gets J
    by central differences)."""
    a = np.linspace(-0.4, 0.4, k)
    share = 2.0 / k
    K, C, gain, v_ref, coupling = 400.0 * share, 2.0 * share, 4.0 * share, 2.0, 0.5
    inertia, k_leg, c_leg, push = 0.16, 900.0, 6.0, 0.2
    all_down = (1 << k) - 1
    n = 2 + k
    d = 2 * n

    def field(x, mask):
        c, s = np.cos(x[1]), np.sin(x[1])
        vz, om = x[n], x[n + 1]
        g = gain * (1.0 + coupling) if mask == all_down else gain
        thrust = g * (1.0 - vz**2 / v_ref**2) * vz
        out = np.zeros(d)
        out[:n] = x[n:d]
        az, alpha = -G, 0.0
        for i in range(k):
            length = LEG + x[2 + i]
            out[n + 2 + i] = -k_leg * x[2 + i] - c_leg * x[n + 2 + i]
            if mask >> i & 1:
                rx = a[i] * c + length * s
                height = x[0] + a[i] * s - length * c
                f = -K * height - C * (vz + om * rx - x[n + 2 + i] * c) + thrust
                az += f
                alpha += rx * f / inertia
                out[n + 2 + i] -= push * f
        out[n], out[n + 1] = az, alpha
        return out

    def events(x):
        c, s = np.cos(x[1]), np.sin(x[1])
        out = np.zeros(k)
        for i in range(k):
            out[i] = -(x[0] + a[i] * s - (LEG + x[2 + i]) * c)
        return out

    x0 = np.zeros(d)
    x0[0] = APEX
    return field, events, x0, float(np.sqrt(2.0 * (APEX - LEG) / G)) + 0.05


def reference_flow(field, events, x0, t_final, k):
    """The end state by solve_ivp, with its own event logic: each stretch ends at the
    first foot height that crosses zero (either way); the region is then read from the
    heights, a foot within 1e-9 of the ground counted by where it is heading (feet that
    land together flip together)."""
    t, x, mask = 0.0, np.array(x0, dtype=float), 0
    for _ in range(4 * k):
        funcs = []
        for i in range(k):
            def ev(_t, y, i=i):
                return events(y)[i]
            ev.terminal, ev.direction = True, (-1 if mask >> i & 1 else 1)
            funcs.append(ev)
        sol = solve_ivp(lambda _t, y, m=mask: field(y, m), (t, t_final), x,
                        method="DOP853", rtol=1e-12, atol=1e-14, events=funcs)
        t, x = sol.t[-1], sol.y[:, -1]
        if sol.status == 0:
            return x
        h = events(x)
        rate = (events(x + 1e-7 * field(x, mask)) - events(x - 1e-7 * field(x, mask))) / 2e-7
        mask = sum(1 << i for i in range(k)
                   if h[i] > 1e-9 or (abs(h[i]) <= 1e-9 and rate[i] > 0))
    raise AssertionError("more stretches than a stance has")


_PRONKING = """
    import json
    import numba
    import numpy as np
    import resource
    import test_run_memory as t
    from bderiv.analysis.system import HybridSystem
    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, resource.RLIM_INFINITY))
    field, events, x0, t_final = t.pronking_body({k})
    system = HybridSystem(numba.njit(field), numba.njit(events), n_events={k}, dim=x0.size)
    D = system.flow_bderivative(x0, t_final)
    V = np.array(json.loads({V!r}))
    print(json.dumps({{"DV": D(V).tolist(), "repr": repr(system)}}))
"""


@linux
def test_flow_map_of_a_four_leg_body_with_central_difference_jacobians():
    """d = 12: the flow map ends (under a 3 GiB address-space limit, in a child) and
    agrees with forward differences of the independent simulation along directions that
    land the feet together and apart."""
    k = 4
    field, events, x0, t_final = pronking_body(k)
    d = x0.size
    V = np.zeros((3, d))
    V[0, 0] = -1.0  # lower: all feet land together, earlier
    V[1, 1] = 0.5  # pitched: the feet land one after the other
    V[2, 2 + 1], V[2, d - 1] = 1.0, 0.3  # leg 1 longer, a rate on the last leg
    out = _child(_PRONKING.format(k=k, V=json.dumps(V.tolist())), timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert "field_jacobian: central differences" in result["repr"]
    DV = np.array(result["DV"])
    base = reference_flow(field, events, x0, t_final, k)
    eps = 1e-6
    for v, dv in zip(V, DV, strict=True):
        fd = (reference_flow(field, events, x0 + eps * v, t_final, k) - base) / eps
        assert np.abs(fd - dv).max() <= 1e-4 * max(1.0, np.abs(fd).max()), (v, fd, dv)
