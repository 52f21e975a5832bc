"""Typing help for viser's GUI handles."""

from __future__ import annotations

from typing import Protocol, TypeVar

T = TypeVar("T")
T_co = TypeVar("T_co", covariant=True)


class ValueHandle(Protocol[T_co]):
    """A GUI input handle with a ``value`` (checkbox, dropdown, slider, number, ...); viser's own base
    class of these is private, so this names what :func:`set_value` needs of one."""

    @property
    def value(self) -> T_co: ...


def set_value(handle: ValueHandle[T], value: T) -> None:
    """``handle.value = value``: set a GUI input's value."""
    # viser 1.1 defines the ``value`` setter apart from its getter (another method in between), so
    # mypy sees a read-only property; this is the one place that assigns it.
    handle.value = value  # type: ignore[misc]  # viser's value setter is invisible to mypy (see above)
