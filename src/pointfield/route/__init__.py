"""The 3D task router: given what you have and what you want, the representation that fits and the
pointfield commands to run, in order, with the reason in one line.

``pointfield route INPUT... [--task WORDS] [--json]`` is :func:`route` then :func:`format_route`
(or :meth:`Route.to_dict`). Inspection (``inputs.py``) reads headers, names and sizes only;
the rules (``rules.py``) are tabled, with what each representation costs, in ``docs/route.md``.

Example::

    >>> from pointfield.route import route
    >>> answer = route("scans/000008.bin", task="robot collision map")
    >>> answer.representation, answer.input.kind
    ('voxels', 'cloud')
"""

from __future__ import annotations

import os
from collections.abc import Sequence

from pointfield.route.inputs import KINDS, Input, inspect_inputs, inspect_path
from pointfield.route.rules import (
    REPRESENTATIONS,
    SCHEMA,
    TASKS,
    Route,
    parse_task,
    plan,
)

__all__ = [
    "KINDS", "REPRESENTATIONS", "SCHEMA", "TASKS", "Input", "Route", "format_route", "inspect_inputs",
    "inspect_path", "parse_task", "route",
]


def route(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]], task: str | None = None
) -> Route:
    """What to do with ``paths`` (a file or folder, or several files of one kind) for ``task``.

    ``task`` is a :data:`TASKS` name or plain words ("mesh for a game engine"); None routes
    for what the input is best at. Raises :class:`~pointfield.PointfieldError` for a path that
    does not exist, one that pointfield cannot identify, inputs of mixed kinds, and words that
    name no task (checked before any file is opened).
    """
    wanted = parse_task(task)
    given = inspect_inputs([paths] if isinstance(paths, (str, os.PathLike)) else list(paths))
    chosen = plan(given, wanted)
    return Route(given, wanted, task, chosen.representation, chosen.reason, tuple(chosen.commands),
                 tuple(chosen.python), tuple(chosen.notes))


def format_route(answer: Route) -> str:
    """The lines ``pointfield route`` prints: input, task, representation, why, then the steps."""
    paths = [str(path) for path in answer.input.paths]
    shown = " ".join(paths[:3]) + (f" (+{len(paths) - 3} more)" if len(paths) > 3 else "")
    rows = [
        ("input", f"{shown}: {answer.input.describe()}"),
        ("task", answer.task or "none given: what it is best at (--task WORDS to say)"),
        ("representation", answer.representation),
        ("why", answer.reason),
    ]
    for label, lines in (("next", answer.commands), ("python", answer.python), ("notes", answer.notes)):
        rows += [(label if i == 0 else "", line) for i, line in enumerate(lines)]
    width = max(len(label) for label, _ in rows) + 2
    return "\n".join(f"{label:<{width}}{text}" for label, text in rows)
