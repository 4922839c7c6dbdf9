"""A call of a compiled function through its address, for intrinsics' code generation.

Numba links a called function's code into its caller and optimises and generates the whole
again there. Called through its address instead, the function's code is generated once: the
kernels' parallel driver calls each block's serial driver so (:mod:`._core`), and the
compiled run the integrator's driver (``models/compiled/_model.drive_at``). Numba has no
public way to emit such a call; this is its own call of a compiled function
(``call_conv.call_function``) on a pointer. Its code is compiled into both, so both cache
keys cover this file.
"""

from __future__ import annotations

from numba.core import cgutils


def call_at(context, builder, address, return_type, argtypes, values):
    """Emit ``f(*values)`` for the compiled ``f: return_type(*argtypes)`` at ``address`` (an
    int64 value); an exception ``f`` raises propagates to the caller. Returns the result."""
    function = context.call_conv.get_function_type(return_type, argtypes)
    pointer = builder.inttoptr(address, function.as_pointer())
    status, result = context.call_conv.call_function(builder, pointer, return_type, argtypes,
                                                     values)
    with cgutils.if_unlikely(builder, status.is_error):
        context.call_conv.return_status_propagate(builder, status)
    return result


def call_at_or(context, builder, address, return_type, argtypes, values, failed):
    """:func:`call_at`, except that where ``f`` raises, the call gives the constant
    ``failed`` and the exception goes no further: for a caller whose own exception would
    be lost, a task of numba's parallel loop on a worker thread (there numba sets it on
    that thread's Python state, which nothing reads; the caller of the loop sees nothing).
    Which exception it was is not kept: the caller runs ``f`` again where it propagates."""
    function = context.call_conv.get_function_type(return_type, argtypes)
    pointer = builder.inttoptr(address, function.as_pointer())
    status, result = context.call_conv.call_function(builder, pointer, return_type, argtypes,
                                                     values)
    return builder.select(status.is_error, context.get_constant(return_type, failed), result)
