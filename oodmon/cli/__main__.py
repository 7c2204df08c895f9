"""``python -m oodmon.cli``: the same as ``python -m oodmon`` and the ``oodmon`` command (as when the
CLI was one module)."""

import sys

from oodmon_console import hold_stops_at_exit

hold_stops_at_exit()  # (first: the last of the exit's clean-ups)

from oodmon.cli import console  # noqa: E402

sys.exit(console())
