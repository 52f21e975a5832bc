"""Every exception class of the package derives from ShapeviewerError (read from the source, so
the check needs none of the heavy imports), and the cancellation errors are one class."""

from __future__ import annotations

import ast
import builtins
from pathlib import Path

import shapeviewer
from shapeviewer.errors import Cancelled, ShapeviewerError

PACKAGE = Path(shapeviewer.__file__).parent
BUILTIN_ERRORS = {
    name for name, value in vars(builtins).items() if isinstance(value, type) and issubclass(value, BaseException)
}


def _exception_classes() -> dict[str, tuple[str, list[str]]]:
    """Class name -> (module file, base names) of every class with an exception among its bases."""
    classes: dict[str, tuple[str, list[str]]] = {}
    aliases: dict[str, str] = {}  # ``RobustnessCancelled = Cancelled``: a class under another name
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ClassDef):
                bases = [b.id if isinstance(b, ast.Name) else ast.unparse(b) for b in node.bases]
                classes[node.name] = (str(path.relative_to(PACKAGE)), bases)
            elif isinstance(node, ast.Assign) and isinstance(node.value, ast.Name) and len(node.targets) == 1:
                if isinstance(node.targets[0], ast.Name):
                    aliases[node.targets[0].id] = node.value.id
    for name, (where, bases) in classes.items():
        classes[name] = (where, [aliases.get(b, b) for b in bases])
    known = {"ShapeviewerError", "Cancelled"}
    grown = True
    while grown:  # classes derived from the package's errors, however deep
        grown = False
        for name, (_, bases) in classes.items():
            if name not in known and any(b in known for b in bases):
                known.add(name)
                grown = True
    return {
        name: entry
        for name, entry in classes.items()
        if name in known or any(b in BUILTIN_ERRORS or b.endswith(("Error", "Exception")) for b in entry[1])
    }


def test_every_exception_class_derives_from_shapeviewer_error():
    classes = _exception_classes()
    assert {"CaptureError", "SegmentTooSmallError", "WorkerDied", "GraspJobError"} <= set(classes)
    stray = {
        f"{where}: {name}({', '.join(bases)})"
        for name, (where, bases) in classes.items()
        if name != "ShapeviewerError" and not any(b in classes and b != "Exception" for b in bases)
    }
    assert not stray, "exception classes outside the ShapeviewerError tree: " + "; ".join(sorted(stray))


def test_cancellation_is_one_class():
    """Every long job stops with the one Cancelled: no other cancellation class or alias exists."""
    import shapeviewer.grasp.pick
    import shapeviewer.grasp.robust
    import shapeviewer.runtime.processes
    import shapeviewer.viewer.dataset.work

    for module in (shapeviewer.grasp.pick, shapeviewer.grasp.robust, shapeviewer.runtime.processes):
        names = [n for n, v in vars(module).items() if isinstance(v, type) and issubclass(v, Cancelled)]
        assert names in ([], ["Cancelled"]), f"{module.__name__} has cancellation classes {names}"
    assert issubclass(Cancelled, ShapeviewerError)


def test_package_errors_keep_their_builtin_base():
    from shapeviewer.completion.pipeline import SegmentTooSmallError
    from shapeviewer.perception.capture import CaptureError

    for error in (CaptureError, SegmentTooSmallError):
        assert issubclass(error, ShapeviewerError) and issubclass(error, ValueError)
