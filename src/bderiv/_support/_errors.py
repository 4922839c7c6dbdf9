"""Refusals about one query of a batch, kept as data until they are shown.

A kernel that cannot answer a query reports a status; the engine turns it into a
:class:`ChainStop` record (what, which row, which event, which region, which value) and
:func:`refusal` into the one exception, a :class:`QueryError`. Its message is rendered
from those fields when shown, so a caller that handed on rows of a larger batch (a chunk,
an event group of a flow map, rows repeated once per direction) moves the error into its
own numbering with :meth:`QueryError.at`: numbers added to numbers, no text rewritten.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._format import transversality_message


class DamagedCacheError(RuntimeError):
    """A function's numba disk cache that cannot be loaded (a damaged or foreign entry),
    named with its files where a compilation failed because of it: never taken for the
    function's refusal of an input (the complex step passes it on)."""


#: where a message names its query
QUERY = "{query}"


class QueryError(ValueError):
    """A ValueError about one row of a batch, its message rendered on demand.

    Parameters
    ----------
    text : str
        The message, with ``{query}`` where the query is named.
    row : int
        The query's flat index in the batch.
    name : str
        The batch's name (``"V"``, ``"W"``, ``"T"``).
    shape : tuple of int
        The batch's leading shape: with two axes or more the query is named by its full
        index (``V[1, 2]``), else by its row (``V[5]``).
    prefix : str
        Where the batch sat (a caller's context, e.g. an event group of a flow map).

    Examples
    --------
    >>> e = QueryError("the result for {query} overflowed", 5, "V", (2, 3))
    >>> str(e)
    'the result for V[1, 2] overflowed'
    >>> str(e.at(row=e.row + 6, shape=(), prefix="in group 0: "))
    'in group 0: the result for V[11] overflowed'
    """

    def __init__(self, text: str, row: int, name: str = "V", shape: tuple = (),
                 prefix: str = ""):
        super().__init__(text, int(row), name, tuple(int(s) for s in shape), prefix)
        self.text, self.row, self.name, self.shape, self.prefix = self.args

    @property
    def query(self) -> str:
        """How the message names the query: ``V[5]`` or ``V[1, 2]``."""
        index = np.unravel_index(self.row, self.shape) if len(self.shape) > 1 else (self.row,)
        return f"{self.name}[{', '.join(str(int(i)) for i in index)}]"

    def __str__(self) -> str:
        return self.prefix + self.text.replace(QUERY, self.query)

    def at(self, row: int | None = None, name: str | None = None, shape: tuple | None = None,
           prefix: str = "") -> QueryError:
        """The same refusal numbered by a caller: its ``row`` in the caller's batch, the
        batch's ``name`` and leading ``shape``, and ``prefix`` before the message."""
        return QueryError(self.text, self.row if row is None else row, name or self.name,
                          self.shape if shape is None else shape, prefix + self.prefix)


class ChainStop(NamedTuple):
    """Why a kernel could not answer one query.

    ``kind``: ``"rate"`` (the chain met a rate ``value`` <= 0 of ``event`` in
    ``region``), ``"corner"`` (a corner model gave a non-finite corner for ``region``) or
    ``"time"`` (the time of ``event`` is about ``2**(value - 1)``, beyond the normal
    float64 numbers). ``row``: the query's row in the batch the kernel ran on; ``region``
    a formatted mask (``_format.format_happened``), ``""`` for none.
    """

    kind: str
    row: int
    event: int
    region: str
    value: float


def refusal(stop: ChainStop, name: str = "V", offset: int = 0,
            inverse: bool = False) -> QueryError:
    """The exception of a :class:`ChainStop`, its row moved by ``offset`` (the first row's
    index in the caller's batch ``name``); ``inverse``: it stopped on an inverse chain.

    Examples
    --------
    >>> str(refusal(ChainStop("time", 2, 1, "", 1100.0), offset=10))[:47]
    'the time of event 1 for V[12] overflows float64'
    """
    where = f"on the chain of {QUERY}{' (inverse map)' if inverse else ''}"
    if stop.kind == "rate":
        text = transversality_message(stop.event, stop.region, stop.value, where)
    elif stop.kind == "corner":
        text = (f"the corner model gave a non-finite value (or left an entry of out "
                f"unwritten) for region mask {stop.region} {where}; corners must be finite")
    elif stop.kind == "time":
        e = int(stop.value)
        text = (f"the time of event {stop.event} for {QUERY} "
                f"{'overflows' if e > 0 else 'underflows'} float64 (about 2**{e - 1}, "
                f"beyond the normal numbers): it cannot be returned. The map itself is "
                f"representable: apply, inverse and orders still work. Event times scale "
                f"with the vector (times(c v) = c times(v)): scale V by a power of two")
    else:
        raise ValueError(f"unknown kind of chain stop {stop.kind!r}")
    return QueryError(text, stop.row + offset, name)
