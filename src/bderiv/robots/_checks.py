"""The robots' argument checks: what a user gives :func:`~bderiv.robots.build.legged_robot`,
:func:`~bderiv.robots.quadrupeds.quadruped`, :func:`~bderiv.robots.quadrupeds.drop_state`
and the robots' methods, refused by name before any work (a short state would otherwise
be read past its end by the compiled configuration, a long one cut silently, and a bad
configuration reach Pinocchio's C++ errors).

The functions a robot hands to its :class:`~bderiv.analysis.system.HybridSystem` check
nothing (the system checks its states once per call already): the robots' public methods
check, then call them.
"""

from __future__ import annotations

import numpy as np

from .._support._format import format_mask
from .._support._validate import check_number, check_state
from .._support._validate_ints import check_distinct, check_int

#: how far from 1 the norm of a configuration's base quaternion may be: it is used as
#: given (not normalised; Pinocchio's ``difference`` and bderiv's exponential take it as
#: a unit quaternion, so a quaternion of norm 1 + 1e-9 moves the base's rotation by that)
QUATERNION_TOL = 1e-9


def check_configuration(q, model, name: str) -> np.ndarray:
    """A configuration (nq,) of ``model`` (a free-flyer first): finite, its base
    quaternion ``q[3:7]`` of unit norm to :data:`QUATERNION_TOL`."""
    arr = check_state(q, model.nq, name, meaning=f"a configuration of the model, nq = "
                      f"{model.nq}: the base's position and quaternion (x, y, z, w), then "
                      f"the joints")
    norm = float(np.linalg.norm(arr[3:7]))
    if not abs(norm - 1.0) <= QUATERNION_TOL:
        raise ValueError(f"{name}[3:7], the base's quaternion (x, y, z, w), must have unit "
                         f"norm (to {QUATERNION_TOL:g}; it is used as given), got "
                         f"{arr[3:7].tolist()} of norm {norm:.17g}; "
                         f"pinocchio.normalize(model, {name}) scales it to norm 1")
    return arr


def check_feet(feet, model) -> tuple:
    """The foot frames: one name (a str) or a sequence of names, each a frame of
    ``model`` and named once."""
    names = (feet,) if isinstance(feet, str) else feet
    try:
        names = tuple(names)
    except TypeError:
        raise TypeError(f"feet must be a foot frame's name or a sequence of them, got "
                        f"{type(feet).__name__} {feet!r}") from None
    bad = [(i, name) for i, name in enumerate(names) if not isinstance(name, str)]
    if bad:
        i, name = bad[0]
        raise TypeError(f"feet must be names of frames (str), got {type(name).__name__} "
                        f"{name!r} at feet[{i}]")
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:  # one foot's contact counted twice: its force doubled, silently
        raise ValueError(f"feet must name each foot once, got {twice} more than once")
    missing = [name for name in names if not model.existFrame(name)]
    if missing or not names:
        frames = [f.name for f in model.frames if "foot" in f.name.lower()]
        raise ValueError(f"feet must name frames of the model, got {missing or 'none'}; "
                         f"the model's frames with 'foot' in their name: {frames}")
    fixed = [name for name in names if model.frames[model.getFrameId(name)].parentJoint == 0]
    if fixed:  # the world's own frames: a "foot" that never moves
        raise ValueError(f"feet must be frames of the robot, got {fixed}, fixed to the world "
                         f"(their parent joint is the universe)")
    return names


def check_law(law: dict, defaults: dict) -> dict:
    """The contact law's parameters given (a subset of ``defaults``' names) as floats:
    finite, ``>= 0`` but ``ground``."""
    unknown = set(law) - set(defaults)
    if unknown:
        raise ValueError(f"{sorted(unknown)} are not parameters of the contact law (its "
                         f"parameters: {', '.join(defaults)})")
    return {name: check_number(value, name, low=-np.inf if name == "ground" else 0.0,
                               strict=False) for name, value in law.items()}


def check_index(k, n: int, name: str) -> int:
    """A foot's index, an integer in ``[0, n)``."""
    return check_int(k, name, low=0, high=n - 1, span=f"in [0, {n})", meaning="a foot's index")


def check_down(down, n: int) -> list:
    """The feet of ``down``: their indices (each in ``[0, n)``, once), or a bool array of
    length ``n`` (True: that foot down); the indices, sorted."""
    arr = np.asarray(down)
    if arr.ndim != 1 or arr.dtype.kind not in "biu" and arr.size:
        raise TypeError(f"down must be a sequence of foot indices (integers in [0, {n})) or "
                        f"{n} booleans, got {down!r}")
    if arr.dtype.kind == "b":
        if arr.size != n:
            raise ValueError(f"down as booleans must have one per foot, {n}, got {arr.size}: "
                             f"{arr.tolist()}")
        return np.flatnonzero(arr).tolist()
    indices = check_distinct(arr.astype(np.int64).tolist(), n, "down", "foot",
                             " (indices, not flags: pass booleans for flags)")
    return sorted(indices)


def check_latches(latches, mask: int, feet) -> None:
    """``mask`` (checked already) against a rigid robot's state's latches ``c`` ((n,), one
    per foot in ``feet``): foot k held in ``mask`` (bit k set) where its latch says it is down,
    ``c_k > 1/2`` (a robot's states have latches 0 or 1; a finite-difference step moves
    them less than 1/2)."""
    down = sum(1 << k for k, c in enumerate(latches) if c > 0.5)
    if down == mask:
        return
    n = len(feet)

    def named(bits):
        return ", ".join(f"{k} ({feet[k]})" for k in range(n) if bits >> k & 1) or "none"

    wrong = [k for k in range(n) if (down ^ mask) >> k & 1]
    raise ValueError(
        f"mask must hold the feet that the latches of x say are down (x[2 nv + k] = c_k: 1 "
        f"down, 0 in the air; down above 1/2): x's latches {np.asarray(latches).tolist()} "
        f"give mask {format_mask(down, n)} (feet down: {named(down)}), got mask "
        f"{format_mask(mask, n)} (feet held: {named(mask)}); they disagree on "
        f"{'feet' if len(wrong) > 1 else 'foot'} {', '.join(map(str, wrong))}. Pass the "
        f"mask of the state's region (a trajectory's mask at that time), or a state whose "
        f"latches agree (robot.state(q, v, down=...))")
