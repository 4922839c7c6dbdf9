"""Stability maps: a gait's periodic orbit and its growth rate over a grid of parameters.

The classic gait-design picture: for every point of a grid of model parameters, find the
periodic orbit (Newton's method with the B-derivative,
:func:`bderiv.analysis.orbit.periodic_orbit`) and decide its stability from the
piecewise-linear return map
(:meth:`PeriodicOrbit.stability <bderiv.analysis.orbit.PeriodicOrbit.stability>`).

**Continuation.** Orbits move continuously with the parameters, so each point starts
Newton's method from the orbit of a neighbour already solved: the grid is swept in
**waves** (anti-diagonals ``i + j = w`` of a two-parameter grid; one index of a
one-parameter grid), every point of a wave starting from its neighbour in the previous
wave (``(i - 1, j)``, else ``(i, j - 1)``; the first point, or one whose neighbours all
failed, from ``x_guess``). The points of one wave are independent of each other.

Continuation follows a **branch**, and a branch can be the wrong one: where a hopping
gait does not exist, Newton's method finds the body standing still (an equilibrium on
the section is a fixed point of P too), and continuing from there follows the standing
branch into the region where the gait exists again. ``accept(orbit) -> bool`` says which
orbits are the ones wanted (for a hopping gait: one with event groups); a point whose
orbit from the neighbour is not accepted, or not found, is solved again from
``x_guess``.

**Where it runs.** Serially in this process, or on a Dask cluster (``dask.distributed``):
``client="local"`` starts a :class:`~distributed.LocalCluster` for the call and closes it
afterwards (its workers ignore Ctrl-C: the call's KeyboardInterrupt ends them), a
:class:`~distributed.Client` is used as it is (Ctrl-C cancels the wave's tasks not begun).
Each wave's points are submitted at once, so a cluster runs up to one wave at a time in
parallel. The model is made on the workers from ``make_system`` and the point's
parameters, so ``make_system`` must pickle (a module-level function, or a
:func:`functools.partial` of one). A compiled model should take the swept values at run time
(``HybridSystem(..., params=p)``, as the bundled gaits do): its functions then compile
once per process (the workers load them from numba's disk cache), not once per point.
Dask is used because a parameter sweep is the job that outgrows one machine; the waves are
this module's own because Dask schedules independent tasks, not continuation.

A point whose orbit is not found (Newton's method fails, the model refuses) is recorded
with its message, not raised: a map has unstable and degenerate regions by nature.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np

from .._limits import LOCAL_WORKERS
from .._support._progress import resolve_progress
from .._support._validate import (
    all_finite,
    check_memory,
    check_number,
    check_real_array,
    check_state,
)
from .._support._validate_ints import check_positive_int
from ._arguments import check_iterations

__all__ = ["StabilityMap", "stability_map"]

#: seconds between looks at a wave's tasks on a cluster (Ctrl-C is seen in between)
_POLL = 0.05


@dataclass(frozen=True, eq=False)
class StabilityMap:
    """Orbits and growth rates over a grid of parameters.

    Attributes
    ----------
    names : tuple of str
        The parameters (one or two).
    values : tuple of ndarray
        The grid's values of each parameter, shapes ``(g_0,)`` (and ``(g_1,)``).
    growth_rate : ndarray, shape (g_0[, g_1])
        The orbit's growth rate (< 1: stable); NaN where no orbit was found.
    period : ndarray, shape (g_0[, g_1])
        The orbit's period; NaN where no orbit was found.
    x0 : ndarray, shape (g_0[, g_1], d)
        The orbit's fixed point on the section; NaN where no orbit was found.
    failures : dict
        ``{grid index (tuple): message}`` for the points without an orbit.
    """

    names: tuple
    values: tuple
    growth_rate: np.ndarray
    period: np.ndarray
    x0: np.ndarray
    failures: dict

    @property
    def stable(self) -> np.ndarray:
        """``growth_rate < 1`` (False where no orbit was found), shape of the grid."""
        with np.errstate(invalid="ignore"):
            return self.growth_rate < 1.0

    def summary(self) -> str:
        """A few lines: the grid, how many orbits are stable, unstable or not found."""
        found = np.isfinite(self.growth_rate)
        grid = " x ".join(f"{name} in [{v[0]:g}, {v[-1]:g}] ({v.size})"
                          for name, v in zip(self.names, self.values, strict=True))
        lines = [f"stability map over {grid}: {int(self.stable.sum())} stable, "
                 f"{int((found & ~self.stable).sum())} unstable, "
                 f"{int((~found).sum())} without an orbit"]
        if found.any():
            lines.append(f"  growth rate {np.nanmin(self.growth_rate):.4g} .. "
                         f"{np.nanmax(self.growth_rate):.4g}")
        for index, message in list(self.failures.items())[:3]:
            lines.append(f"  no orbit at {self._point(index)}: {message}")
        return "\n".join(lines)

    def _point(self, index) -> str:
        return ", ".join(f"{name}={v[i]:g}"
                         for name, v, i in zip(self.names, self.values, index, strict=True))


def stability_map(make_system, grid, x_guess, section, *, period_guess=None, accept=None,
                  n_directions=200, iterations=300, client=None, progress=None,
                  **orbit_options) -> StabilityMap:
    """Find the periodic orbit and its growth rate at every point of a parameter grid.

    Parameters
    ----------
    make_system : callable
        ``make_system(**params) -> HybridSystem`` (an object with a ``system`` attribute,
        such as an :class:`~bderiv.examples.Example`, is accepted too). Must pickle when a
        Dask ``client`` is used.
    grid : dict
        ``{name: values}`` for one or two parameters, each a 1-d sequence of numbers.
    x_guess : array_like, shape (d,)
        Start of Newton's method at the first point (and where no neighbour has an orbit);
        checked, before the grid runs, against the model built at the grid's first point.
    section : callable
        ``section(x) -> float``, crossed upward once per stride (must pickle with Dask).
    period_guess : float, optional
        Passed to :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.
    accept : callable, optional
        ``accept(orbit) -> bool``: the orbits wanted (default: every orbit found); a
        point whose orbit from its neighbour is refused is solved again from
        ``x_guess``, and recorded as a failure if that one is refused too. Must pickle
        with Dask.
    n_directions, iterations : int
        Of each orbit's :meth:`~bderiv.analysis.orbit.PeriodicOrbit.stability`
        (``n_directions >= 1``, ``iterations >= 2``).
    client : None, "local" or distributed.Client
        None: serially in this process; "local": a LocalCluster for this call; a Client:
        its cluster.
    progress : None, bool or callable
        ``progress(done, total)`` after each point (True: a tqdm bar).
    **orbit_options
        Passed to ``periodic_orbit`` (``tol``, ``max_iter``, ``simultaneity_tol``, ...).

    Returns
    -------
    StabilityMap

    Raises
    ------
    TypeError, ValueError
        Before the grid runs, for an argument of the wrong type, shape or range (named):
        a point's failure is recorded, but a bad argument would fail at every point. A
        ValueError too for a grid whose map (``2 + d`` floats a point) the memory the
        process may still take cannot hold.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv.examples import gaits
    >>> smap = stability_map(gaits.pronking, {"gain": [3.0, 4.0]}, gaits.pronking().x0,
    ...                      gaits.apex_section, period_guess=0.5, n_directions=50,
    ...                      iterations=100)
    >>> smap.stable.tolist(), np.round(smap.growth_rate, 2).tolist()  # doctest: +SKIP
    ([True, True], [0.86, 0.78])
    """
    if not callable(make_system):
        raise TypeError(f"make_system must be callable (make_system(**params) -> "
                        f"HybridSystem), got {type(make_system).__name__}")
    names, axes = _check_grid(grid)
    if period_guess is not None:
        period_guess = check_number(period_guess, "period_guess")
    n_directions = check_positive_int(n_directions, "n_directions")
    iterations = check_iterations(iterations)
    # checked here: a bad one would be refused at every point, each recorded as "no orbit"
    first = {n: float(a[0]) for n, a in zip(names, axes, strict=True)}
    x_guess, system = _check_guess(make_system, first, x_guess)
    shape = tuple(a.size for a in axes)
    # the map's arrays are the one thing the size of the grid: refused now if they cannot
    # fit; the waves are made one at a time (a 5000 x 5000 grid listed whole took 4.6 GB
    # and 45 s before its first point)
    smap = _empty_map(names, axes, x_guess.size)
    task = _Task(make_system, names, section, period_guess, accept, n_directions, iterations,
                 orbit_options, x_guess, (first, system))
    run, close = _runner(client)
    progress = resolve_progress(progress, desc="stability map", unit="point")
    done, total = 0, math.prod(shape)
    try:
        for wave in _waves(shape):
            starts = [_start(smap, index, x_guess) for index in wave]
            params = [{n: float(a[i]) for n, a, i in zip(names, axes, index, strict=True)}
                      for index in wave]
            for index, result in zip(wave, run(task, params, starts), strict=True):
                _record(smap, index, result)
                done += 1
                if progress is not None:
                    progress(done, total)
    except KeyboardInterrupt:  # Ctrl-C returns now, an own cluster closes in a thread (the
        # interpreter waits for it at exit: its processes take a second to end)
        threading.Thread(target=close, kwargs={"interrupted": True},
                         name="bderiv-close-cluster").start()
        raise
    except BaseException:
        close()
        raise
    close()
    return smap


def _check_grid(grid):
    """(names, axes) of a grid of one or two parameters, each axis a finite 1-d array."""
    if not isinstance(grid, dict) or not 1 <= len(grid) <= 2:
        raise TypeError(f"grid must be a dict of one or two parameters {{name: values}}, got "
                        f"{type(grid).__name__}" + (f" of {len(grid)}" if isinstance(
                            grid, dict) else ""))
    axes = []
    for name, values in grid.items():
        if not isinstance(name, str):
            raise TypeError(f"grid's keys must be parameter names (str, keywords of "
                            f"make_system), got {type(name).__name__} {name!r}")
        what = f"grid[{name!r}] must be a non-empty 1-d sequence of finite numbers, got"
        try:
            a = check_real_array(values, f"grid[{name!r}]")
        except ValueError:  # a ragged nest of sequences
            raise ValueError(f"{what} {values!r}") from None
        if a.ndim != 1 or a.size == 0 or not all_finite(a):
            got = f"shape {a.shape}" if a.ndim != 1 or a.size == 0 else f"{a.tolist()}"
            raise ValueError(f"{what} {got}")
        axes.append(a.astype(np.float64))
    return tuple(grid), tuple(axes)


def _check_guess(make_system, params, x_guess):
    """``(x_guess, system)``: ``x_guess`` checked against the model of the grid's first
    point (built here, so that a guess of the wrong size is refused before the grid runs,
    not at every point), and that model."""
    system = make_system(**params)
    system = getattr(system, "system", system)  # an Example carries its system
    dim = getattr(system, "dim", None)
    if not isinstance(dim, int | np.integer) or not callable(
            getattr(system, "periodic_orbit", None)):
        raise TypeError(f"make_system must return a HybridSystem (or an object with a "
                        f"system attribute, such as an Example), got {type(system).__name__}")
    at = ", ".join(f"{k}={v:g}" for k, v in params.items())
    return check_state(x_guess, dim, "x_guess",
                       meaning=f"a state of the model that make_system({at}) builds"), system


def _waves(shape):
    """Grid indices by wave, each wave made when it is reached (the grid is never listed
    whole): anti-diagonals ``sum(index) = w``, w ascending, each in ascending order."""
    if len(shape) == 1:
        return ([(i,)] for i in range(shape[0]))
    rows, cols = shape
    return ([(i, w - i) for i in range(max(0, w - cols + 1), min(rows, w + 1))]
            for w in range(rows + cols - 1))


def _start(smap, index, x_guess):
    """The fixed point of a solved neighbour in the previous wave, else ``x_guess``."""
    for axis in range(len(index)):
        if index[axis] > 0:
            prev = index[:axis] + (index[axis] - 1,) + index[axis + 1:]
            if prev not in smap.failures:
                return smap.x0[prev].copy()
    return x_guess


class _Task:
    """One point: its orbit and growth rate, or the message of the failure (picklable)."""

    def __init__(self, make_system, names, section, period_guess, accept, n_directions,
                 iterations, orbit_options, x_guess, built=None):
        self.make_system, self.names, self.section = make_system, names, section
        self.period_guess, self.accept, self.orbit_options = period_guess, accept, orbit_options
        self.n_directions, self.iterations, self.x_guess = n_directions, iterations, x_guess
        # (params, system) of the first point, built to check x_guess: taken by the first
        # call in this process (a robot's model loads its URDF), never shipped to workers
        self._built = built

    def __getstate__(self):
        return {**self.__dict__, "_built": None}

    def __call__(self, params, start):
        """(x0, period, growth rate) of the orbit, or (None, message, None)."""
        built, self._built = self._built, None
        if built is not None and built[0] == params:
            system = built[1]
        else:
            system = self.make_system(**params)
            system = getattr(system, "system", system)  # an Example carries its system
        starts = [start] if np.array_equal(start, self.x_guess) else [start, self.x_guess]
        for x in starts:
            try:
                orbit = system.periodic_orbit(x, self.section, period_guess=self.period_guess,
                                              **self.orbit_options)
            except (ValueError, RuntimeError) as exc:  # no orbit here: recorded, not raised
                failure = f"{type(exc).__name__}: {exc}"
                continue
            if self.accept is None or self.accept(orbit):
                st = orbit.stability(n_directions=self.n_directions, iterations=self.iterations)
                return orbit.x0, orbit.period, st.growth_rate
            failure = f"the orbit found (x0 = {orbit.x0}) is not accepted"
        return None, failure, None


def _runner(client):
    """``(run(task, params, starts) -> results, close())`` for the chosen scheduler."""
    if client is None:
        return (lambda task, params, starts: [task(p, s) for p, s in zip(params, starts,
                                                                          strict=True)],
                lambda interrupted=False: None)
    try:
        from distributed import Client

        from .._support._dask import end_now, start_local
    except ImportError as exc:
        raise ImportError("client= needs the optional dependency distributed: install "
                          "`pip install 'bderiv[dask]'`, or pass client=None") from exc
    own = isinstance(client, str)
    if own:
        if client != "local":
            raise ValueError(f'client must be None, "local" or a distributed.Client, got '
                             f"{client!r}")
        client, cluster = start_local(LOCAL_WORKERS)
    elif not isinstance(client, Client):
        raise TypeError(f'client must be None, "local" or a distributed.Client, got '
                        f"{type(client).__name__}")

    def run(task, params, starts):
        futures = client.map(task, params, starts, pure=False)
        try:
            # waited for here, polled: a Ctrl-C inside distributed's blocking calls left
            # their waits in the client's event loop ("Task exception was never retrieved
            # ... AllExit" from gather; "NameError: cannot access free variable 'future'"
            # from wait, when it came before the wait had begun), printed on stderr
            while not all(f.done() for f in futures):
                time.sleep(_POLL)
            return client.gather(futures)
        except KeyboardInterrupt:
            if not own:  # a user's cluster is free at once: the wave's tasks not started are
                # cancelled (a task running goes on to its end: a thread is not stopped)
                client.cancel(futures)
            raise  # an own cluster's workers are ended (close(interrupted=True))
        except BaseException:
            client.cancel(futures)
            raise

    def close(interrupted=False):
        if interrupted:  # Ctrl-C: the workers end now, not after a point (_dask.end_now)
            end_now(client, cluster)
        else:
            client.close()
            cluster.close()

    return run, (close if own else (lambda interrupted=False: None))


def _empty_map(names, axes, d) -> StabilityMap:
    """The map to fill, its arrays NaN; refused (a ValueError naming the sizes) where they
    would not fit in what the process may still take."""
    shape = tuple(a.size for a in axes)
    check_memory(math.prod(shape) * (2 + d) * 8, None,
                 f"the map's arrays over a {' x '.join(map(str, shape))} grid (growth rate, "
                 f"period and the fixed point x0 of size {d} at each point)",
                 "map a coarser grid, or the grid in parts (one call each)")
    return StabilityMap(names, axes, np.full(shape, np.nan), np.full(shape, np.nan),
                        np.full((*shape, d), np.nan), {})


def _record(smap, index, result) -> None:
    """A point's ``(x0, period, growth rate)`` into the map, or its failure's message."""
    x, p, rate = result
    if x is None:
        smap.failures[index] = p
    else:
        smap.x0[index], smap.period[index], smap.growth_rate[index] = x, p, rate
