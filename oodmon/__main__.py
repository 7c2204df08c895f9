"""``python -m oodmon``: the same as the ``oodmon`` command."""

import sys

from oodmon_console import hold_stops_at_exit

hold_stops_at_exit()  # (first: the last of the exit's clean-ups)

from oodmon.cli import console  # noqa: E402

sys.exit(console())
