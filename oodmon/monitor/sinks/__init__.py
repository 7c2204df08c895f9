"""Where the monitor's records go: memory (tests), MCAP files, Rerun (file or live)."""

from __future__ import annotations

from oodmon.monitor.sinks.base import MemorySink, Sink, SinkGroup, SinkWarning
from oodmon.monitor.sinks.mcap import McapSink
from oodmon.monitor.sinks.rerun import FooterMemoryWarning, RerunSink

__all__ = ["FooterMemoryWarning", "McapSink", "MemorySink", "RerunSink", "Sink", "SinkGroup", "SinkWarning"]
