"""oodmon's JSON files (thresholds, detectors' and models' metadata, baselines, bench results,
training state) are written whole or not at all, and a failed write names its file."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from oodmon.errors import ConfigError
from oodmon.jsonfile import read_json, write_json

# A real failing write without a full disk: the process's file size limit (RLIMIT_FSIZE) makes
# write() fail with EFBIG past it, as ENOSPC does on a full disk (SIGXFSZ ignored, as Python's
# default handler would kill the process instead).
_LIMITED = textwrap.dedent("""
    import resource, signal, sys
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
    from oodmon.jsonfile import write_json
    try:
        write_json(sys.argv[1], {"numbers": list(range(5000))})
    except OSError as error:
        print(error)
        sys.exit(3)
""")


def test_a_failed_write_keeps_the_old_file_leaves_nothing_beside_it_and_names_the_file(tmp_path):
    path = tmp_path / "threshold.json"
    write_json(path, {"value": 1.5})
    before = path.read_text()
    assert json.loads(before) == {"value": 1.5} and before.endswith("\n")
    result = subprocess.run([sys.executable, "-c", _LIMITED, str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 3, result.stderr
    assert "File too large" in result.stdout and str(path) in result.stdout  # write()'s own error names no file
    assert path.read_text() == before  # the old file, whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["threshold.json"]  # no threshold.json.part left


def test_a_write_that_fails_with_no_old_file_leaves_none(tmp_path):
    path = tmp_path / "new.json"
    result = subprocess.run([sys.executable, "-c", _LIMITED, str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 3 and not any(tmp_path.iterdir())


def test_sorted_keys_for_models_metadata(tmp_path):
    write_json(tmp_path / "model.json", {"b": 1, "a": {"d": 2, "c": 3}}, sort_keys=True)
    assert (tmp_path / "model.json").read_text() == '{\n "a": {\n  "c": 3,\n  "d": 2\n },\n "b": 1\n}\n'


def test_a_read_stops_past_its_bound_where_a_file_never_ends(tmp_path, monkeypatch):
    # /dev/zero given as a threshold was read whole, 24 GB, until the system killed the command
    monkeypatch.setattr("oodmon.jsonfile.MOST_JSON_BYTES", 1000)
    with pytest.raises(ConfigError, match=r"^threshold file /dev/zero holds more than 0 MB, far more than any JSON file"):
        read_json("/dev/zero", name="threshold file")
    big = tmp_path / "big.json"
    big.write_text(json.dumps(list(range(400))))  # 1,890 bytes
    with pytest.raises(ConfigError, match="holds more than"):
        read_json(big)
    small = tmp_path / "small.json"
    small.write_text(json.dumps(list(range(100))) + "\n")  # 391 bytes
    assert read_json(small) == list(range(100))
