"""The oodmon command as a person uses it: real output, one-line errors, non-zero exits."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import pytest

from oodmon.cli import main


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "oodmon", *args], capture_output=True, text=True)


def test_envs_lists_the_whole_grid_as_json(capsys):
    assert main(["envs", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 150
    assert {"task": "cartpole", "spec": "cartpole:length=2.0", "parameter": "length", "value": 2.0, "default": 0.5} in rows
    assert {"task": "pong", "spec": "pong:motion_blur@3", "parameter": "motion_blur", "value": "radius=15, sigma=8",
            "default": None} in rows


def test_envs_table_for_one_task(capsys):
    assert main(["envs", "--task", "pong"]) == 0
    out = capsys.readouterr().out
    assert "The paper's OOD variants (20)" in out and "pong:pixelate@5" in out and "cartpole" not in out


def test_envs_show_pong_writes_clean_and_corrupted_side_by_side(tmp_path):
    out = tmp_path / "frames" / "frame.png"
    result = _run("envs", "show", "pong:pixelate@3", "--out", str(out))
    assert result.returncode == 0, result.stderr
    assert f"wrote {out}" in result.stdout
    image = cv2.imread(str(out))
    assert image.shape == (784, 640, 3)
    left, right = image[22:442, :320], image[22:442, 320:]
    assert (left != right).any()


def test_envs_show_physics_reports_returns_and_plots(tmp_path, capsys):
    out = tmp_path / "trace.png"
    assert main(["envs", "show", "cartpole:length=2.0", "--onset", "100", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "against 500.0 in the ID env" in text
    assert cv2.imread(str(out)) is not None


@pytest.mark.parametrize(
    "args, words",
    [
        (["envs", "show", "cartpole:lenght=2"], "has no parameter 'lenght'"),
        (["envs", "show", "cartpole:length=-1"], "length=-1.0 is not allowed"),
        (["envs", "show", "pong:pixelate@9"], "severity=9 is not allowed"),
        (["envs", "show", "pong:fog@1"], "unknown corruption 'fog'"),
        (["envs", "show", "cartpole:length"], "malformed variant spec"),
    ],
)
def test_cli_errors_are_one_line_without_a_traceback(args, words):
    result = _run(*args)
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("oodmon: error: ") and words in lines[0], result.stderr
    assert "Traceback" not in result.stderr


def test_demo_runs_and_writes_its_pictures(tmp_path, capsys):
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "the monitor is not built yet" in out
    assert "cartpole:length=2.0" in out and "falls" in out
    pictures = sorted(p.name for p in tmp_path.iterdir())
    assert pictures == sorted(["cartpole_length2_onset100.png", "pong_gaussian_noise_3.png", "pong_impulse_noise_3.png",
                               "pong_motion_blur_3.png", "pong_pixelate_3.png"])
