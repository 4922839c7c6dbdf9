"""Small corner tables without a model, for the command line, the figures and the tests.

Each function returns ``(Dh, F)``: the event Jacobian, shape (n, d), and the corner table,
shape (2**n, d), row ``mask`` the field of the region where the events whose bits are set
in ``mask`` have happened (mathematics.md section 1); pass them to :class:`~bderiv.BDerivative`.
"""

from __future__ import annotations

import numpy as np


def three_event_table():
    """A 3-event system in R^3 whose event order can be overtaken (mathematics.md section 3).

    Returns
    -------
    Dh : ndarray, shape (3, 3)
    F : ndarray, shape (8, 3)

    Examples
    --------
    >>> from bderiv import BDerivative
    >>> BDerivative(*three_event_table())([-1.0, -2.0, -3.0])
    array([-2.9, -3.8, -6.8])
    """
    F = np.ones((8, 3))
    F[0b001] = (1.0, 0.1, 1.0)  # after event 0 alone, h_1 grows ten times slower
    F[0b011] = (1.0, 0.5, 2.0)
    F[0b111] = (1.5, 1.0, 2.0)
    return np.eye(3), F


def planar_table():
    """A 2-event system in the plane (d = n = 2) for the 2-D figures.

    Returns
    -------
    Dh : ndarray, shape (2, 2)
    F : ndarray, shape (4, 2)
    """
    Dh = np.array([[1.0, 0.3], [0.2, 1.0]])
    F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    return Dh, F
