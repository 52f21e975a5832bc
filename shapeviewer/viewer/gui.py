"""Help for the panel: typing for viser's GUI handles, counted nouns for its texts, and the checks of
what a browser sends through the handles."""

from __future__ import annotations

from typing import Protocol, TypeVar

import viser

from .sources import one_line

T = TypeVar("T")
T_co = TypeVar("T_co", covariant=True)


class ValueHandle(Protocol[T_co]):
    """A GUI input handle with a ``value`` (checkbox, dropdown, slider, number, ...); viser's own base
    class of these is private, so this names what :func:`set_value` needs of one."""

    @property
    def value(self) -> T_co: ...


class ProgressBar(Protocol):
    """What the panel does with a progress bar of ``gui.add_progress_bar``: sets its value (percent)
    and shows or hides it (viser does not export the handle's class)."""

    visible: bool

    @property
    def value(self) -> float: ...


def set_value(handle: ValueHandle[T], value: T) -> None:
    """``handle.value = value``: set a GUI input's value."""
    # viser 1.1 defines the ``value`` setter apart from its getter (another method in between), so
    # mypy sees a read-only property; this is the one place that assigns it.
    handle.value = value  # type: ignore[misc]  # viser's value setter is invisible to mypy (see above)


def plural(n: int, noun: str, nouns: str | None = None) -> str:
    """``"1 segment"``, ``"3 segments"``: a count and its noun for the panel's texts (``nouns``: the
    plural when it is not ``noun + "s"``)."""
    return f"{n} {noun if n == 1 else (nouns or noun + 's')}"


# ----------------------------------------------------------------------------------------------
# Checking what a browser sends: viser applies any value (and any property, options included) a
# client's GUI update message names, so a value is trusted only once the server has checked it.


def unlisted_problem(value: str, offered: tuple[str, ...]) -> str | None:
    """Why a dropdown's ``value`` is refused: it is not one of ``offered``, the entries the server
    itself lists now (never the dropdown's own ``options``, which a client can rewrite too); None
    when it is one of them."""
    if value in offered:
        return None
    return f"{one_line(value)}: not one of the files the Server file list offers"


def take_upload(handle: viser.GuiUploadButtonHandle) -> viser.UploadedFile:
    """The file an upload button received, which the button then lets go of: viser keeps the last
    upload's bytes as the button's value until the next one, so a refused or unreadable file would
    otherwise stay in memory for as long as the tab is open."""
    file = handle.value
    # The handle's state, not its ``value`` setter: the setter would send the empty file to the
    # browser and call the button's upload callbacks again.
    handle._impl.value = viser.UploadedFile(file.name, b"")
    return file
