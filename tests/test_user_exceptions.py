"""An exception raised inside a model's Python function reaches the user as it was raised
(its type, message and traceback: users catch their own), with one note (Python 3.11+)
that says which function raised it, its arguments (state, region mask, event) and the
time where the integrator knows it. bderiv's own errors, KeyboardInterrupt and a batch's
cancellation are left as they are; on Python 3.10 nothing is added."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from bderiv import HybridSystem
from bderiv._support import _format
from bderiv.models.compiled import Cancelled
from bderiv.models.section import Section

notes = pytest.mark.skipif(sys.version_info < (3, 11), reason="exceptions take notes on 3.11+")


def clock(x):
    return np.array([x[1] - 5.0])


def steady(x, mask):
    return np.array([1.0, 1.0])


def _notes(exc):
    return [n for n in getattr(exc, "__notes__", ()) if n.startswith("bderiv:")]


@notes
def test_a_field_that_raises_is_named_with_its_state_mask_and_time():
    def field(x, mask):
        if x[1] > 1.0:
            return np.array([1.0 / 0.0, 1.0])  # ZeroDivisionError: Python floats
        return np.array([0.0, 1.0])

    model = HybridSystem(field, clock, n_events=1, dim=2)
    with pytest.raises(ZeroDivisionError, match="division by zero") as info:
        model.simulate(np.array([0.0, 0.0]), 3.0)
    assert type(info.value) is ZeroDivisionError  # the user's own, not wrapped
    assert info.traceback[-1].name == "field"  # its traceback down to the raising line
    (note,) = _notes(info.value)
    assert note.startswith("bderiv: raised by the model's field(x, mask), called with "
                           "x = [0.0, 1."), note
    assert ", mask = 0b0 (bit k set = event k happened) at t = 1." in note


@notes
def test_events_that_raise_are_named_with_the_time_and_region_of_the_run():
    def events(x):
        if x[1] > 0.5:
            return np.array([x[1] - 5.0, x[3]])  # IndexError
        return np.array([x[1] - 5.0, -1.0])

    model = HybridSystem(steady, events, n_events=2, dim=2)
    with pytest.raises(IndexError) as info:
        model.simulate(np.array([0.0, 0.0]), 3.0)
    (note,) = _notes(info.value)
    assert note.startswith("bderiv: raised by the model's events(x), called with x = [0."), note
    assert " at t = 0." in note
    assert note.endswith(" in region mask 0b00 (bit k set = event k happened)"), note


@notes
def test_a_reset_that_raises_is_named_with_its_event_and_the_stop_s_time():
    def reset(x, mask, k):
        return x[[0, 1, 2]]  # IndexError: the state has two entries

    model = HybridSystem(steady, clock, n_events=1, dim=2, reset=reset)
    with pytest.raises(IndexError) as info:
        model.simulate(np.array([0.0, 0.0]), 8.0)
    (note,) = _notes(info.value)
    assert note.startswith("bderiv: raised by the model's reset(x, mask, k), called with "
                           "x = [5.0, 5.0], mask = 0b0 (bit k set = event k happened), k = 0 "
                           "at t = "), note
    assert float(note.rsplit(" ", 1)[1]) == pytest.approx(5.0)  # the stop's time


@notes
def test_with_params_the_note_gives_the_x_the_function_got():
    def field(x, mask):
        return np.array([x[1], x[3]])  # IndexError: one parameter, x[2]

    model = HybridSystem(field, clock, n_events=1, dim=2, params=[0.5])
    with pytest.raises(IndexError) as info:
        model.calls.eval_field(np.array([1.0, 2.0]), 0)  # outside a run: no time
    assert _notes(info.value) == [
        "bderiv: raised by the model's field(x, mask), called with x = [1.0, 2.0, 0.5], "
        "mask = 0b0 (bit k set = event k happened)"]


@notes
def test_a_note_is_added_once_through_nested_models():
    """A field that runs another model: the inner model's function raised; the note is
    the innermost call's alone, not one per model the exception passes."""

    def broken(x, mask):
        raise KeyError("inner")

    inner = HybridSystem(broken, clock, n_events=1, dim=2)

    def outer_field(x, mask):
        inner.simulate(np.array([0.0, 0.0]), 1.0)
        return np.array([1.0, 1.0])

    outer = HybridSystem(outer_field, clock, n_events=1, dim=2)
    with pytest.raises(KeyError) as info:
        outer.flow_bderivative(np.array([0.0, 0.0]), 1.0)  # the numerical Jacobian too
    assert len(_notes(info.value)) == 1
    assert _notes(info.value)[0].startswith(
        "bderiv: raised by the model's field(x, mask), called with x = [0.0, 0.0], mask = "
        "0b0 (bit k set = event k happened) at t = 0.0")


@notes
def test_an_exception_object_raised_again_is_noted_for_its_new_call():
    """A function that raises an exception object it keeps (one made once, at import):
    each raise is noted for its own call, not the first run's state and time."""
    kept = RuntimeError("out of range")

    def field(x, mask):
        if x[1] > 0.5:
            raise kept
        return np.array([1.0, 1.0])

    system = HybridSystem(field, clock, n_events=1, dim=2)
    for start in (0.0, 0.3):  # x(t) = (t, start + t): each note's x is its run's at its t
        with pytest.raises(RuntimeError) as err:
            system.simulate(np.array([0.0, start]), 2.0)
        (note,) = _notes(err.value)
        x0, x1 = map(float, note.split("x = [")[1].split("]")[0].split(", "))
        when = float(note.split(" at t = ")[1].split()[0])
        assert x1 > 0.5 and abs(x0 - when) < 1e-12 and abs(x1 - start - when) < 1e-12, note


@notes
def test_a_batch_of_runs_says_which_start_the_raise_came_from():
    def field(x, mask):
        if x[0] > 10.0:
            raise ZeroDivisionError("far out")
        return np.array([1.0, 1.0])

    system = HybridSystem(field, clock, n_events=1, dim=2)
    X0 = np.array([[0.0, 0.0], [10.5, 0.0], [0.0, 1.0]])
    with pytest.raises(ZeroDivisionError, match="far out") as err:
        system.simulate_many(X0, 1.0)
    notes = _notes(err.value)
    assert len(notes) == 2 and notes[0].startswith("bderiv: raised by the model's field")
    assert notes[1] == "bderiv: in the run from X0[1] = [10.5, 0.0]", notes


@notes
def test_a_reset_jacobian_that_raises_in_a_flow_map_is_named_with_the_group_s_time():
    def reset(x, mask, k):
        return x.copy()

    def reset_jacobian(x, mask, k):
        raise KeyError("no Jacobian here")

    system = HybridSystem(steady, clock, n_events=1, dim=2, reset=reset,
                          reset_jacobian=reset_jacobian)
    with pytest.raises(KeyError) as err:
        system.flow_bderivative(np.zeros(2), 8.0)
    (note,) = _notes(err.value)
    assert note.startswith("bderiv: raised by the model's reset_jacobian(x, mask, k), "
                           "called with x = [5.0, 5.0]"), note
    assert abs(float(note.split(" at t = ")[1]) - 5.0) < 1e-12, note  # the group's time


def test_bderivs_own_errors_are_not_noted():
    """A refused output names the function already; an error of bderiv raised inside a
    user's function (a model run inside it) is left as bderiv wrote it."""

    def short(x, mask):
        return np.ones(1)

    with pytest.raises(ValueError, match=r"field\(x, mask=0\) must return an array of "
                                         r"shape \(2,\)") as info:
        HybridSystem(short, clock, n_events=1, dim=2).simulate(np.zeros(2), 1.0)
    assert not _notes(info.value)

    inner = HybridSystem(steady, clock, n_events=1, dim=2)

    def field(x, mask):
        inner.simulate(np.zeros(2), -1.0)  # bderiv refuses t_final
        return np.ones(2)

    with pytest.raises(ValueError, match="t_final") as info:
        HybridSystem(field, clock, n_events=1, dim=2).simulate(np.zeros(2), 1.0)
    assert not _notes(info.value)


@notes
def test_a_user_s_own_value_error_is_noted():
    def field(x, mask):
        raise ValueError("my own check")

    with pytest.raises(ValueError, match="my own check") as info:
        HybridSystem(field, clock, n_events=1, dim=2).simulate(np.zeros(2), 1.0)
    assert len(_notes(info.value)) == 1


@pytest.mark.parametrize("kind", [KeyboardInterrupt, Cancelled])
def test_interrupts_and_cancellations_are_not_touched(kind):
    def field(x, mask):
        raise kind

    with pytest.raises(kind) as info:
        HybridSystem(field, clock, n_events=1, dim=2).simulate(np.zeros(2), 1.0)
    assert not hasattr(info.value, "__notes__")


@notes
def test_a_section_that_raises_is_named():
    def section(x):
        return {}["no such key"]

    with pytest.raises(KeyError) as info:
        Section(section, 2)(np.array([0.5, -1.0]))
    assert _notes(info.value) == [
        "bderiv: raised by the model's section(x), called with x = [0.5, -1.0]"]


def test_without_notes_the_exception_is_left_as_it_is(monkeypatch):
    """Python 3.10 (no ``add_note``): the exception as raised, no wrapper in the way."""
    monkeypatch.setattr(_format, "NOTES", False)

    def field(x, mask):
        raise ZeroDivisionError("mine")

    model = HybridSystem(field, clock, n_events=1, dim=2)
    assert model.calls._field is field
    with pytest.raises(ZeroDivisionError, match="mine") as info:
        model.simulate(np.zeros(2), 1.0)
    assert not hasattr(info.value, "__notes__")
