"""Every bad input gets exit code 2 and one line on stderr that names the parameter and the value,
never a traceback, and no input file is changed. Run in-process through ``main()``."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest

from oodmon.cli import main

DATA = Path(__file__).parent / "data"
ID_LOG = DATA / "cartpole-ensemble-id.mcap"
BENCH_RESULTS = Path(__file__).parents[1] / "results" / "bench" / "cartpole.json"


def _threshold(**changes) -> dict:
    from oodmon.agents import load
    from oodmon.monitor.monitor import policy_hash

    base = {"value": 4.6, "score": "chosen_std", "consecutive": 3, "mode": "episode", "far": 0.05, "n_episodes": 50,
            "n_steps": 25000, "quantiles": {}, "task": "cartpole", "method": "ensemble", "window": 1,
            "policy_hash": policy_hash(load("cartpole", "ensemble"))}
    return base | changes


def _log_with_a_broken_episode_record(path: Path) -> None:
    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="test")
        schema = writer.register_schema("oodmon.Episode", "jsonschema", b"{}")
        episode = writer.register_channel("/oodmon/episode", "json", schema)
        scores = writer.register_channel("/oodmon/episode_scores", "json", schema)
        writer.add_metadata("oodmon.run", {"task": "cartpole", "method": "ensemble", "threshold": "1.0"})
        writer.add_message(episode, log_time=0, publish_time=0, data=json.dumps({"episode": 0, "variant": "cartpole"}).encode())
        writer.add_message(scores, log_time=0, publish_time=0, data=json.dumps(
            {"episode": 0, "length": 0, "score_f64": "", "shifted_u8": "", "alarm_u8": ""}).encode())
        writer.finish()


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    """The inputs folder, in a folder of this module's own: each case hashes that one (a copy of a log
    sits beside the inputs), not the session's temporary folder, which holds every earlier test's files."""
    root = tmp_path_factory.mktemp("bad-input") / "inputs"
    root.mkdir()
    (root / "thr.json").write_text(json.dumps(_threshold()))
    bad = {
        "thr-number.json": "5", "thr-string.json": '"abc"', "thr-null.json": "null", "thr-broken.json": "{value: 1",
        "thr-value-abc.json": json.dumps(_threshold(value="abc")),
        "thr-value-null.json": json.dumps(_threshold(value=None)),
        "thr-value-nan.json": json.dumps(_threshold(value=float("nan"))),
        "thr-consecutive-0.json": json.dumps(_threshold(consecutive=0)),
        "thr-mode.json": json.dumps(_threshold(mode="weird")),
        "thr-far.json": json.dumps(_threshold(far=1.5)),
        "thr-score.json": json.dumps(_threshold(score="foo")),
        "thr-window.json": json.dumps(_threshold(window=-2)),
        "thr-pong.json": json.dumps(_threshold(task="pong")),
        "thr-dropout.json": json.dumps(_threshold(method="dropout")),
        "thr-weights.json": json.dumps(_threshold(policy_hash="sha256:" + "0" * 64)),
        "thr-sb3.json": json.dumps(_threshold(task="my_envs:MyEnv-v0", method="sb3")),
        "base-metrics-5.json": json.dumps({"metrics": 5}),
        "base-row-5.json": json.dumps({"metrics": {"k": 5}}),
        "base-high.json": json.dumps({"metrics": {"k": {"auroc": "high"}}}),
        "base-unknown.json": json.dumps({"metrics": {"k": {"speed": 1.0}}}),
        "base-tolerance.json": json.dumps({"tolerance": "x", "metrics": {}}),
        "bench-row-without-method.json": json.dumps({"config": {}, "rows": [{"variant": "cartpole:length=2.0", "mean": 0.9}]}),
        "base-list.json": "[1, 2]",
        "not-a-log.mcap": "hello",
    }
    for name, text in bad.items():
        (root / name).write_text(text)
    (root / "base-binary.json").write_bytes(bytes(range(256)))
    (root / "a-file").write_text("")
    (root / "t2.json.detectors").write_text("")  # where calibrate --out t2.json would put its fitted detectors
    (root / "model.zip").write_bytes(b"PK\x03\x04 a user's model")  # read by nothing: refused before any load
    (root / "a-folder").mkdir()
    (root / "thr.json.detectors").mkdir()  # a threshold's fitted detectors, where calibrate --out thr.json puts them
    _log_with_a_broken_episode_record(root / "broken-episode.mcap")
    return root


RUN = ["run", "--task", "cartpole", "--method", "ensemble", "--episodes", "1"]
CALIBRATE = ["calibrate", "--task", "cartpole", "--method", "ensemble", "--episodes", "45"]

# (id, argv with {d} for the inputs folder, environment, what the one line must name)
CASES = [
    ("run-seed-negative", [*RUN, "--seed", "-1"], {}, ["--seed", "-1"]),
    ("run-episodes-0", [*RUN, "--episodes", "0"], {}, ["--episodes", "0"]),
    ("run-episodes-negative", [*RUN, "--episodes", "-3"], {}, ["--episodes", "-3"]),
    ("run-episodes-text", [*RUN, "--episodes", "many"], {}, ["--episodes", "many"]),
    ("run-onset-negative", [*RUN, "--onset", "-5"], {}, ["--onset", "-5"]),
    ("run-onset-without-variant", [*RUN, "--onset", "10"], {}, ["--onset 10", "no --variant"]),
    ("run-detectors-missing", [*RUN, "--detectors", "{d}/nope"], {},
     ["nope does not exist: fitted detectors are a folder"]),
    ("run-detectors-a-threshold", [*RUN, "--detectors", "{d}/thr.json"], {},
     ["thr.json is a file, not a folder", "beside it: ", "thr.json.detectors"]),
    ("run-split-mb-0", [*RUN, "--mcap", "{d}/x.mcap", "--mcap-split-mb", "0"], {}, ["--mcap-split-mb", "0"]),
    ("run-split-without-mcap", [*RUN, "--mcap-split-episodes", "10"], {}, ["--mcap-split-episodes", "give --mcap"]),
    ("run-no-footer-without-rrd", [*RUN, "--rrd-no-footer"], {}, ["--rrd-no-footer", "give --rrd too"]),
    ("run-serve-memory-without-serve", [*RUN, "--serve-memory", "64"], {}, ["--serve-memory", "give --serve too"]),
    ("run-serve-memory-negative", [*RUN, "--serve", "--serve-memory", "-1"], {}, ["--serve-memory", "-1"]),
    ("run-render-pong", ["run", "--task", "pong", "--method", "ensemble", "--render"], {}, ["--render", "pong"]),
    ("run-port-0", [*RUN, "--port", "0"], {}, ["--port", "0"]),
    ("run-port-too-big", [*RUN, "--port", "70000"], {}, ["--port", "70000"]),
    ("run-mcap-in-proc", [*RUN, "--mcap", "/proc/x.mcap"], {}, ["--mcap", "/proc/x.mcap"]),
    ("run-mcap-parent-is-a-file", [*RUN, "--mcap", "{d}/a-file/x.mcap"], {}, ["--mcap", "a-file"]),
    ("run-mcap-is-a-folder", [*RUN, "--mcap", "{d}/a-folder"], {}, ["--mcap", "a-folder", "folder"]),
    ("run-mcap-name-too-long", [*RUN, "--mcap", "{d}/" + "x" * 300 + ".mcap"], {}, ["--mcap", "too long"]),
    ("run-rrd-parent-is-a-file", [*RUN, "--rrd", "{d}/a-file/x.rrd"], {}, ["--rrd", "a-file"]),
    ("run-mcap-same-as-rrd", [*RUN, "--mcap", "{d}/same", "--rrd", "{d}/same"], {}, ["--rrd", "same", "--mcap"]),
    ("run-mcap-is-the-threshold", [*RUN, "--threshold", "{d}/thr.json", "--mcap", "{d}/thr.json"], {},
     ["--mcap", "thr.json", "--threshold"]),
    ("run-mcap-is-the-vec-normalize", ["run", "--sb3", "{d}/model.zip", "--env", "CartPole-v1", "--vec-normalize",
                                       "{d}/a-file", "--mcap", "{d}/a-file", "--overwrite"], {},
     ["--mcap", "a-file", "--vec-normalize"]),
    ("run-overwrite-a-model", [*RUN, "--mcap", "{d}/model.zip", "--overwrite"], {},
     ["model.zip", "is not an MCAP log", "give another path"]),
    ("run-on-alarm-empty", [*RUN, "--threshold", "{d}/thr.json", "--on-alarm", " "], {},
     ["--on-alarm ' ' is not allowed", "shell command"]),
    ("run-on-alarm-without-threshold", [*RUN, "--on-alarm", "true"], {}, ["--on-alarm", "give --threshold"]),
    ("run-threshold-missing", [*RUN, "--threshold", "{d}/nothing.json"], {}, ["nothing.json", "does not exist"]),
    ("run-threshold-a-number", [*RUN, "--threshold", "{d}/thr-number.json"], {}, ["thr-number.json", "5"]),
    ("run-threshold-a-string", [*RUN, "--threshold", "{d}/thr-string.json"], {}, ["thr-string.json", "abc"]),
    ("run-threshold-null", [*RUN, "--threshold", "{d}/thr-null.json"], {}, ["thr-null.json", "None"]),
    ("run-threshold-not-json", [*RUN, "--threshold", "{d}/thr-broken.json"], {}, ["thr-broken.json", "not valid JSON"]),
    ("run-threshold-value-abc", [*RUN, "--threshold", "{d}/thr-value-abc.json"], {}, ["value='abc'"]),
    ("run-threshold-value-null", [*RUN, "--threshold", "{d}/thr-value-null.json"], {}, ["value=None"]),
    ("run-threshold-value-nan", [*RUN, "--threshold", "{d}/thr-value-nan.json"], {}, ["value=nan", "silence"]),
    ("run-threshold-consecutive-0", [*RUN, "--threshold", "{d}/thr-consecutive-0.json"], {}, ["consecutive=0"]),
    ("run-threshold-mode", [*RUN, "--threshold", "{d}/thr-mode.json"], {}, ["mode='weird'"]),
    ("run-threshold-far", [*RUN, "--threshold", "{d}/thr-far.json"], {}, ["far=1.5"]),
    ("run-threshold-score", [*RUN, "--threshold", "{d}/thr-score.json"], {}, ["score='foo'"]),
    ("run-threshold-window", [*RUN, "--threshold", "{d}/thr-window.json"], {}, ["window=-2"]),
    ("run-threshold-other-task", [*RUN, "--threshold", "{d}/thr-pong.json"], {}, ["task 'pong'", "--force"]),
    ("run-threshold-other-method", [*RUN, "--threshold", "{d}/thr-dropout.json"], {}, ["method 'dropout'", "--force"]),
    ("run-threshold-other-weights", [*RUN, "--threshold", "{d}/thr-weights.json"], {}, ["other weights", "sha256:0000"]),
    ("run-variant-huge-length", [*RUN, "--variant", "cartpole:length=1e308"], {}, ["length=1e+308"]),
    ("run-variant-zero-gravity", [*RUN, "--variant", "cartpole:gravity=0"], {}, ["gravity=0"]),
    ("run-variant-other-task", [*RUN, "--variant", "pendulum:g=20.0"], {}, ["pendulum:g=20.0", "cartpole"]),
    ("run-model-missing", ["run", "--task", "cartpole", "--model", "{d}/no-model"], {}, ["no-model", "model.json"]),
    ("calibrate-episodes-negative", [*CALIBRATE, "--episodes", "-1", "--out", "{d}/t.json"], {}, ["--episodes", "-1"]),
    ("calibrate-out-in-proc", [*CALIBRATE, "--out", "/proc/t.json"], {}, ["--out", "/proc/t.json"]),
    ("calibrate-out-is-a-folder", [*CALIBRATE, "--out", "{d}/a-folder"], {}, ["--out", "a-folder"]),
    # A name typed wrong: the model it reads, or a file that holds no threshold, is not replaced.
    ("calibrate-out-is-the-sb3-model", ["calibrate", "--sb3", "{d}/model.zip", "--env", "CartPole-v1", "--out",
                                        "{d}/model.zip"], {}, ["--out", "model.zip", "is also --sb3"]),
    ("calibrate-out-is-a-log", [*CALIBRATE, "--out", "{d}/broken-episode.mcap"], {},
     ["--out", "broken-episode.mcap", "holds no threshold", "not valid JSON"]),
    ("calibrate-out-is-a-baseline", [*CALIBRATE, "--out", "{d}/base-metrics-5.json"], {},
     ["--out", "base-metrics-5.json", "holds no threshold", "lacks value"]),
    ("calibrate-far-1.5", [*CALIBRATE, "--far", "1.5", "--out", "{d}/t.json"], {}, ["--far", "1.5"]),
    ("calibrate-far-too-small-for-n", [*CALIBRATE, "--far", "0.01", "--out", "{d}/t.json"], {}, ["far=0.01", "230", "45"]),
    ("calibrate-confidence-1", [*CALIBRATE, "--confidence", "1", "--out", "{d}/t.json"], {}, ["--confidence", "1"]),
    ("calibrate-consecutive-0", [*CALIBRATE, "--consecutive", "0", "--out", "{d}/t.json"], {}, ["--consecutive", "0"]),
    ("calibrate-window-0", [*CALIBRATE, "--window", "0", "--out", "{d}/t.json"], {}, ["--window", "0"]),
    ("calibrate-score-unknown", [*CALIBRATE, "--score", "foo", "--out", "{d}/t.json"], {}, ["score 'foo'"]),
    ("check-baseline-binary", ["check", str(ID_LOG), "--baseline", "{d}/base-binary.json"], {}, ["base-binary.json", "JSON"]),
    ("check-baseline-metrics-5", ["check", str(ID_LOG), "--baseline", "{d}/base-metrics-5.json"], {}, ["metrics", "5"]),
    ("check-baseline-row-5", ["check", str(ID_LOG), "--baseline", "{d}/base-row-5.json"], {}, ["metrics['k']=5"]),
    ("check-baseline-auroc-high", ["check", str(ID_LOG), "--baseline", "{d}/base-high.json"], {},
     ["['auroc']='high'"]),
    ("check-baseline-unknown-metric", ["check", str(ID_LOG), "--baseline", "{d}/base-unknown.json"], {}, ["'speed'"]),
    ("check-baseline-tolerance-x", ["check", str(ID_LOG), "--baseline", "{d}/base-tolerance.json"], {}, ["tolerance='x'"]),
    ("check-baseline-a-list", ["check", str(ID_LOG), "--baseline", "{d}/base-list.json"], {}, ["base-list.json", "[1, 2]"]),
    ("check-baseline-a-benchs-results", ["check", str(ID_LOG), "--baseline", str(BENCH_RESULTS)], {},
     ["cartpole.json is the results of `oodmon bench`", "bench ... --baseline"]),
    ("check-tolerance-flag-x", ["check", str(ID_LOG), "--baseline", "{d}/b.json", "--tolerance", "x"], {},
     ["--tolerance", "'x'"]),
    ("check-update-over-a-threshold", ["check", "{d}/../log.mcap", "--baseline", "{d}/thr.json", "--update"], {},
     ["--baseline", "thr.json", "holds no baseline", "not an oodmon baseline"]),
    ("check-update-over-the-log", ["check", "{d}/../log.mcap", "--baseline", "{d}/../log.mcap", "--update"], {},
     ["--baseline", "log.mcap"]),
    ("replay-not-mcap", ["replay", "{d}/not-a-log.mcap"], {}, ["not-a-log.mcap", "not an MCAP file"]),
    ("replay-missing", ["replay", "{d}/missing.mcap"], {}, ["missing.mcap", "does not exist"]),
    ("replay-episode-record-lacks-fields", ["replay", "{d}/broken-episode.mcap"], {}, ["broken-episode.mcap", "env_id"]),
    ("replay-plots-is-a-file", ["replay", str(ID_LOG), "--plots", "{d}/a-file"], {}, ["--plots", "a-file"]),
    ("replay-plots-takes-the-log", ["replay", "--plots", str(ID_LOG)], {}, ["--plots", "is a log", "LOGS --plots DIR"]),
    ("replay-plots-a-picture", ["replay", str(ID_LOG), "--plots", "{d}/plot.png"], {}, ["plot.png names a picture"]),
    ("threads-huge", ["envs", "--task", "cartpole"], {"OODMON_TORCH_THREADS": "99999999999"},
     ["OODMON_TORCH_THREADS", "99999999999"]),
    ("threads-text", ["envs", "--task", "cartpole"], {"OODMON_TORCH_THREADS": "two"}, ["OODMON_TORCH_THREADS", "two"]),
    ("threads-zero", ["envs", "--task", "cartpole"], {"OODMON_TORCH_THREADS": "0"}, ["OODMON_TORCH_THREADS", "0"]),
    ("bench-trials-0", ["bench", "--task", "cartpole", "--trials", "0"], {}, ["--trials", "0"]),
    ("bench-fit-episodes-2", ["bench", "--task", "cartpole", "--fit-episodes", "2"], {}, ["--fit-episodes", "2"]),
    ("bench-workers-negative", ["bench", "--task", "cartpole", "--workers", "-1"], {}, ["--workers", "-1"]),
    ("bench-method-unknown", ["bench", "--task", "cartpole", "--methods", "bayes"], {}, ["--methods", "bayes"]),
    ("bench-onsets-reversed", ["bench", "--task", "cartpole", "--protocol", "monitor", "--onsets", "60,20"], {},
     ["--onsets", "'60,20' is not LOW,HIGH"]),
    ("bench-onsets-paper", ["bench", "--task", "cartpole", "--onsets", "20,60"], {}, ["--onsets", "--protocol monitor"]),
    ("bench-failure-oodmon-task", ["bench", "--task", "cartpole", "--protocol", "monitor", "--failure", "terminated"], {},
     ["failure='terminated'", "oodmon tells cartpole's failures itself"]),
    ("bench-baseline-missing", ["bench", "--task", "cartpole", "--out", "{d}/b", "--baseline", "{d}/missing.json"], {},
     ["missing.json", "does not exist"]),
    ("bench-baseline-not-a-result", ["bench", "--task", "cartpole", "--out", "{d}/b", "--baseline", "{d}/thr.json"], {},
     ["thr.json", "not an oodmon bench result"]),
    ("bench-baseline-of-logs", ["bench", "--task", "cartpole", "--out", "{d}/b", "--baseline", "{d}/base-row-5.json"],
     {},
     ["base-row-5.json is a baseline of logs", "oodmon check LOGS --baseline"]),
    ("bench-baseline-row-without-method", ["bench", "--task", "cartpole", "--out", "{d}/b", "--baseline",
                                           "{d}/bench-row-without-method.json"], {},
     ["bench-row-without-method.json", "an entry of its 'rows' lacks method, variant"]),
    ("bench-tolerance-negative", ["bench", "--task", "cartpole", "--baseline", "{d}/thr.json", "--tolerance", "-1"], {},
     ["--tolerance", "-1"]),
    ("bench-results-over-a-threshold", ["bench", "--task", "cartpole", "--out", "{d}/b", "--results", "{d}/thr.json"],
     {}, ["--results", "thr.json", "holds no bench result"]),
    ("bench-results-parent-is-a-file", ["bench", "--task", "cartpole", "--out", "{d}/b", "--results", "{d}/a-file/r.json"],
     {}, ["--results", "a-file"]),
    # refused before the trainings (a score was first read when the calibration's first step was scored)
    ("bench-score-unknown", ["bench", "--task", "cartpole", "--out", "{d}/b", "--score", "bogus"], {},
     ["unknown score 'bogus'"]),
    ("bench-score-of-other-actions", ["bench", "--task", "pendulum", "--out", "{d}/b", "--score", "margin_std"], {},
     ["score 'margin_std' needs discrete actions (DQN)"]),
    ("bench-masks-of-ensembles", ["bench", "--task", "cartpole", "--out", "{d}/b", "--methods", "ensemble", "--masks",
                                  "fixed"], {}, ["masks='fixed'", "Dropout and DropConnect"]),
    ("evaluate-episodes-0", ["evaluate", "--task", "cartpole", "--method", "ensemble", "--episodes", "0"], {},
     ["--episodes", "0"]),
    ("evaluate-fail-fraction", ["evaluate", "--task", "cartpole", "--method", "ensemble", "--fail-fraction", "2"], {},
     ["--fail-fraction", "2"]),
    ("evaluate-workers-negative", ["evaluate", "--task", "cartpole", "--method", "ensemble", "--workers", "-2"], {},
     ["--workers", "-2"]),
    ("calibrate-workers-not-a-number", ["calibrate", "--task", "cartpole", "--method", "ensemble", "--workers", "two",
                                        "--out", "{d}/t.json"], {}, ["--workers", "two"]),
    ("train-steps-0", ["train", "--task", "cartpole", "--method", "dropout", "--out", "{d}/t", "--steps", "0"], {},
     ["--steps", "0"]),
    ("train-out-is-a-file", ["train", "--task", "cartpole", "--method", "dropout", "--out", "{d}/a-file"], {},
     ["--out", "a-file"]),
    ("task-unknown", ["calibrate", "--task", "hopper", "--method", "dropout", "--out", "{d}/t.json"], {},
     ["--task", "hopper"]),
    ("envs-show-bad-spec", ["envs", "show", "cartpole:lenght=2"], {}, ["lenght"]),
    # A flag the command does not have: said by the command's own parser, with the flag it has that is closest.
    ("run-mistyped-flag", ["run", "--task", "cartpole", "--method", "ensemble", "--rerun", "{d}/r.rrd"], {},
     ["oodmon run: error", "--rerun", "did you mean --rrd?", "see oodmon run --help"]),
    ("envs-show-mistyped-flags", ["envs", "show", "cartpole:length=2.0", "--ot", "{d}/x.png", "--taks=pong"], {},
     ["oodmon envs show: error", "--ot: did you mean --out?", "--taks"]),
    ("replay-unknown-flag", ["replay", str(ID_LOG), "--zzz"], {}, ["oodmon replay: error", "--zzz (see oodmon replay"]),
    ("frame-stack-without-sb3", [*CALIBRATE, "--frame-stack", "4", "--out", "{d}/t.json"], {}, ["--frame-stack", "--sb3"]),
    ("frame-stack-1", ["calibrate", "--sb3", "{d}/m.zip", "--env", "CartPole-v1", "--frame-stack", "1", "--out",
                       "{d}/t.json"], {}, ["--frame-stack 1", "VecFrameStack"]),
    ("validate-sb3-threshold-without-sb3", ["validate", "{d}/thr-sb3.json"], {},
     ["thr-sb3.json", "--sb3 ZIP --env my_envs:MyEnv-v0"]),
    ("run-sb3-threshold-without-sb3", ["run", "--threshold", "{d}/thr-sb3.json"], {},
     ["thr-sb3.json", "--sb3 ZIP --env my_envs:MyEnv-v0"]),
    ("fit-only-misspelt", ["fit-detectors", "--task", "cartpole", "--method", "ensemble", "--only", "spread,dynamcs",
                           "--out", "{d}/det"], {}, ["--only", "'dynamcs' (did you mean 'dynamics'?)"]),
    ("run-variant-task-misspelt", [*RUN, "--variant", "cartpol:length=2"], {},
     ["'cartpol' (did you mean 'cartpole'?); choose one of cartpole, pendulum, pong"]),
    ("calibrate-score-misspelt", [*CALIBRATE, "--score", "chosen_sd", "--out", "{d}/t.json"], {},
     ["'chosen_sd' (did you mean 'chosen_std'?)"]),
    # a name the system refuses (scripts/fuzz_cli.py, 2026-12-05: a traceback until then)
    ("sb3-name-too-long", ["calibrate", "--sb3", "x" * 300, "--env", "CartPole-v1", "--out", "{d}/t.json"], {},
     ["x" * 300, "does not exist"]),
    ("sb3-empty", ["calibrate", "--sb3", "", "--env", "CartPole-v1", "--out", "{d}/t.json"], {},
     [". is a folder; an SB3 model is the .zip file"]),
    # a file that never ends: read to its bound, not until the system kills the command (24 GB before)
    ("validate-a-threshold-that-never-ends", ["validate", "/dev/zero"], {},
     ["threshold file /dev/zero", "holds more than 256 MB"]),
    # counts beyond memory (scripts/fuzz_api.py, 2026-12-05: numpy's "Maximum allowed dimension exceeded" in a
    # traceback, exit 3)
    ("calibrate-window-beyond-memory", ["calibrate", "--task", "cartpole", "--method", "ensemble", "--window",
                                        str(10**30), "--out", "{d}/t.json"], {}, ["--window", "from 1 to 10000000"]),
    # calibration episodes that are not held out (2026-12-05: calibrated on them, the promise did not hold)
    ("calibrate-on-the-detectors-fitting-episodes", ["calibrate", "--task", "cartpole", "--method", "ensemble", "--seed",
                                                     "600000", "--out", "{d}/t.json"], {},
     ["seeds 600,000-600,049", "the detectors' fitting episodes (seeds 600,000-600,089)", "e.g. 200000"]),
    # the detectors folder beside --out is checked before any episode, and (since 2026-12-06) made only once written
    ("calibrate-detectors-folder-is-a-file", [*CALIBRATE, "--detector", "dynamics", "--obs-noise", "0.01", "--out",
                                              "{d}/t2.json"], {},
     ["--out (its detectors folder)", "t2.json.detectors is a file; give a folder"]),
    ("fit-detectors-given-detectors", ["fit-detectors", "--task", "cartpole", "--method", "ensemble", "--detectors",
                                       "{d}", "--out", "{d}/det"], {}, ["unrecognized arguments: --detectors"]),
]


def _hashes(folder: Path) -> dict[str, str]:
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_there_are_at_least_forty_cases_as_many_as_the_readme_says():
    assert len(CASES) >= 40 and len({case[0] for case in CASES}) == len(CASES)
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert f"(`tests/test_bad_input.py` runs {len(CASES)} such cases;" in readme  # (it said 95 of 98 until 2026-12-03)


@pytest.mark.parametrize("argv, environment, named", [case[1:] for case in CASES], ids=[case[0] for case in CASES])
def test_bad_input_is_one_clear_line_with_exit_code_2(files, argv, environment, named, capsys, monkeypatch):
    import shutil

    shutil.copyfile(ID_LOG, files.parent / "log.mcap")
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    before = _hashes(files.parent) | _hashes(DATA)
    code = main([arg.replace("{d}", str(files)) for arg in argv])
    err = capsys.readouterr().err
    lines = err.rstrip("\n").splitlines()  # (no blank line before it either)
    assert code == 2, err
    assert len(lines) == 1, err
    assert "Traceback" not in err and "error" in lines[0]
    for text in named:
        assert text in lines[0], lines[0]
    after = _hashes(files.parent) | _hashes(DATA)
    assert {k: v for k, v in after.items() if k in before} == before  # no input changed
    assert not [k for k in after if k not in before and not k.endswith(".mcap")]  # nothing written
