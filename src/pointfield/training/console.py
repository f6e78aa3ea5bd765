"""What training says while it runs: lines above tqdm's bar, flushed, and how often to speak off a terminal.

On a terminal a bar shows progress (tqdm, on stderr). Where the output goes to a file or a pipe
(a batch job, a CI log) the bar is silent, and stdout is block-buffered: without a flush a log
shows nothing until the run ends. So every line is flushed as it is written, and long work
(training, an evaluation) writes a status line at least every :data:`STATUS_SECONDS` instead of
the bar, as nerfstudio's console writer does.
"""

from __future__ import annotations

import sys
from typing import Any

STATUS_SECONDS = 60.0
"""Off a terminal, the longest training or an evaluation stays silent."""


def write_line(line: str) -> None:
    """``line`` on stdout above any bar, flushed."""
    from tqdm.auto import tqdm

    tqdm.write(line, file=sys.stdout)
    sys.stdout.flush()


def progress_bar(show: bool, **options: Any):
    """A tqdm bar on stderr when ``show`` and stderr is a terminal; a disabled one (``.disable``) otherwise."""
    from tqdm.auto import tqdm

    # disable=None: a bar on a terminal, nothing when output goes to a file or a pipe.
    return tqdm(disable=None if show else True, file=sys.stderr, dynamic_ncols=True, leave=False, **options)
