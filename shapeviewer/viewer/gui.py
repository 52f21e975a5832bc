"""Typing help for viser's GUI handles."""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from viser._gui_handles import _GuiInputHandle  # the base of every input handle; viser does not export it

T = TypeVar("T")


def set_value(handle: _GuiInputHandle[T], value: T) -> None:
    """``handle.value = value``: set a GUI input's value."""
    # viser 1.1 defines the ``value`` setter apart from its getter (another method in between), so
    # mypy sees a read-only property; this is the one place that assigns it.
    handle.value = value  # type: ignore[misc]  # viser's value setter is invisible to mypy (see above)
