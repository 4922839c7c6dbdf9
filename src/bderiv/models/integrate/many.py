"""Many runs of one model: :func:`run_many` integrates a batch of start states, one run each.

The runs are independent: :func:`~bderiv.models.integrate.run.run` from each start state,
one after the other in this process. Each run is exactly the one ``simulate`` makes (the
same trajectory, to the bit); what the batch adds is one validation of the settings, a
progress bar of the runs done, and errors that name the start state they came from. The
stop logic of a run is Python (one code path for both integrators), so the runs are not
spread over threads: a compiled model's stretches run in compiled code, one run at a time.
Ctrl-C stops the batch within the run it lands in (a compiled run returns to Python
between slices of steps of about 0.2 s; a Python one at every field evaluation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..._progress import SimulationProgress, resolve_progress
from ..._validate import check_number, check_points, check_positive_int
from .run import run

__all__ = ["Trajectories", "check_states", "run_many"]

#: the bar of a batch's runs (drawn as a simulation's: after a delay, on a terminal)
_BAR_FORMAT = ("{desc}: {percentage:3.0f}%|{bar}| {n:.0f} of {total:.0f} runs "
               "[{elapsed}<{remaining}]")


@dataclass(frozen=True, eq=False)
class Trajectories:
    """Result of :meth:`HybridSystem.simulate_many
    <bderiv.models.system.HybridSystem.simulate_many>`: one trajectory per start state.

    Attributes
    ----------
    trajectories : tuple of Trajectory
        The runs, in the order of the start states (row-major over the leading shape).
    x_final : ndarray, shape (..., d)
        The final states, in the shape of ``X0``.
    mask_final : ndarray of int64, shape (...)
        The final region masks.

    ``len``, iteration and indexing (``runs[i]``: a Trajectory) go over ``trajectories``.
    """

    trajectories: tuple
    x_final: np.ndarray
    mask_final: np.ndarray

    def __len__(self):
        return len(self.trajectories)

    def __iter__(self):
        return iter(self.trajectories)

    def __getitem__(self, i):
        return self.trajectories[i]


def check_states(X0, dim: int) -> tuple[np.ndarray, tuple]:
    """Start states ``(..., d)`` as C-contiguous float64 rows ``(m, d)`` and the leading
    shape; a ValueError names what was expected and what came, or the first row that is
    not finite."""
    return check_points(X0, dim, "X0", meaning="start states of this system, one per row")


def run_many(system, X0, lead, t_final, *, simultaneity_tol, options, max_groups,
             section=None, progress=None) -> Trajectories:
    """:func:`~bderiv.models.integrate.run.run` from every row of ``X0``.

    Parameters
    ----------
    system : HybridSystem
    X0 : ndarray, shape (m, d)
        Checked start states (:func:`check_states`).
    lead : tuple
        The leading shape the results take (``m`` = its product).
    t_final, simultaneity_tol, options, max_groups, section
        As for :func:`~bderiv.models.integrate.run.run` (checked here once).
    progress : None, bool or callable ``progress(done, total)``
        None: a bar of the runs done once the batch has lasted a few seconds (on a
        terminal, as a simulation's); False: none; True: a tqdm bar from the start; a
        callable: called after each run.

    Returns
    -------
    Trajectories

    Raises
    ------
    ValueError, RuntimeError
        As a run raises them, the message prefixed with the start state's index.
    """
    t_final = check_number(t_final, "t_final")
    simultaneity_tol = check_number(simultaneity_tol, "simultaneity_tol", strict=False)
    max_groups = check_positive_int(max_groups, "max_groups")
    m = X0.shape[0]
    watch = None
    if progress is None:
        watch = SimulationProgress(m, desc="simulate_many", bar_format=_BAR_FORMAT)
        report = None
    else:
        report = resolve_progress(progress, desc="simulate_many", unit="run")
    trajectories = []
    try:
        for i in range(m):
            try:
                traj = run(system, X0[i].copy(), t_final, simultaneity_tol=simultaneity_tol,
                           options=options, max_groups=max_groups, section=section)
            except (ValueError, RuntimeError) as exc:
                if type(exc) not in (ValueError, RuntimeError):
                    raise
                where = ", ".join(str(int(j)) for j in np.unravel_index(i, lead)) if lead \
                    else ""
                raise type(exc)(f"the run from X0[{where}] = {X0[i]}: {exc}") from exc
            trajectories.append(traj)
            if watch is not None:
                watch(i + 1)
            elif report is not None:
                report(i + 1, m)
    finally:
        if watch is not None:
            watch.close()
    d = X0.shape[1]
    x_final = np.array([traj.x_final for traj in trajectories]).reshape(lead + (d,))
    masks = np.array([traj.mask_final for traj in trajectories], dtype=np.int64)
    return Trajectories(tuple(trajectories), x_final, masks.reshape(lead))
