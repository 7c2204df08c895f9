"""oodmon's other files (pictures, detector sets, exported agents, a training's checkpoints) are
written whole or not at all, and a failed write is one OSError naming its file, whatever library
wrote it: torch's and safetensors' writers raise errors of their own on a full disk (measured on a
600 KB tmpfs: RuntimeError "[enforce fail at inline_container.cc:672] . unexpected pos ...",
SafetensorError "... No space left on device"), which reached the user as tracebacks."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

# Real failing writes without a full disk, as tests/test_jsonfile.py makes them: the process's file
# size limit (RLIMIT_FSIZE) makes write() fail past it (EFBIG), as ENOSPC does on a full disk.
_WRITERS = textwrap.dedent("""
    import json, resource, signal, sys
    from pathlib import Path

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    import torch
    from safetensors.numpy import save_file

    from oodmon.envs.preview import save_rgb
    from oodmon.outputs import save_figure, write_whole

    folder = Path(sys.argv[1])
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    big = np.random.default_rng(0).random(4000).astype(np.float32)
    fig, ax = plt.subplots()
    ax.imshow(np.random.default_rng(0).random((200, 200)))
    writers = {
        "figure.png": lambda path: save_figure(fig, path),
        "picture.png": lambda path: save_rgb((np.random.default_rng(0).random((200, 200, 3)) * 255).astype(np.uint8), path),
        "checkpoint.pt": lambda path: write_whole(path, lambda part: torch.save({"w": torch.from_numpy(big)}, part)),
        "weights.safetensors": lambda path: write_whole(path, lambda part: save_file({"w": big}, str(part))),
    }
    messages = {}
    for name, write in writers.items():
        try:
            write(folder / name)
            messages[name] = "written"
        except OSError as error:
            messages[name] = str(error)
    print(json.dumps(messages))
""")


def test_a_failed_write_is_one_error_naming_the_file_and_leaves_nothing(tmp_path):
    result = subprocess.run([sys.executable, "-c", _WRITERS, str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    messages = json.loads(result.stdout.strip().splitlines()[-1])
    assert set(messages) == {"figure.png", "picture.png", "checkpoint.pt", "weights.safetensors"}
    for name, message in messages.items():
        assert message.startswith(f"{tmp_path / name} could not be written (") and message.endswith(
            " MB free on its disk)"), message
    assert list(tmp_path.iterdir()) == []  # no part file, no half of a file


def _socket_file(path):
    """A Unix socket bound at ``path`` (its file stays until removed): a name that is not a regular
    file, which any user may make (a device takes root), and which open() cannot read."""
    import socket

    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    server.close()
    return path


def test_a_name_that_is_not_a_regular_file_is_refused_never_replaced_or_removed(tmp_path):
    # As root, `calibrate --out /dev/zero` moved its threshold over /dev/zero (a regular file of 840
    # bytes in its place, found by scripts/fuzz_cli.py on 2026-12-05), and McapSink("/dev/null",
    # overwrite=True) read it as an empty log, torn at its start, and removed it
    import os

    import pytest

    from oodmon.errors import ConfigError
    from oodmon.jsonfile import special_file, write_json
    from oodmon.monitor import McapSink, RerunSink, Threshold
    from oodmon.monitor.records import RunInfo
    from oodmon.outputs import check_output_file, write_whole

    assert special_file("/dev/null") == "a character device" and special_file(tmp_path / "none.json") is None
    with pytest.raises(ConfigError, match=r"^--out /dev/null is a character device, not a file: .* give a file name"):
        check_output_file("/dev/null", parameter="--out")  # (the check opens it to append: harmless if it regressed)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    sock = _socket_file(tmp_path / "sock")
    threshold = Threshold(1.0, "chosen_std", 1, "episode", 0.05, 45, 9_000)
    run = RunInfo("cartpole", "ensemble", "chosen_std", 1.0, "r", "h", {})
    for path, kind in ((fifo, "a named pipe"), (sock, "a socket")):
        assert special_file(path) == kind
        # (the sinks check before they read a log's first bytes there: a pipe would wait for a writer)
        writes = [lambda: write_json(path, {"a": 1}), lambda: threshold.save(path),
                  lambda: write_whole(path, lambda part: part.write_text("x")),
                  lambda: McapSink(path, overwrite=True).open(run), lambda: RerunSink(path=path, overwrite=True).open(run)]
        for write in writes:
            with pytest.raises(ConfigError, match=f"is {kind}, not a file"):
                write()
            assert special_file(path) == kind  # still there, as it was
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fifo", "sock"]  # no part file left beside them
