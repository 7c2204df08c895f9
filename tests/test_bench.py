"""The bench end to end on a tiny grid: models, failing variants, monitored logs, replayed AUROCs."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import sys
from pathlib import Path

import numpy as np
import pytest
from safetensors.torch import load_file

from oodmon.bench import BenchConfig, best_per_method, paper_label, run_bench
from oodmon.bench.report import unsolved_trials
from oodmon.bench.run import _in_worker as _bench_in_worker
from oodmon.errors import ConfigError
from oodmon.replay import compute_metrics, read_log, read_logs
from tests.helpers import load_script, run_cli, wait_until_dead

SPECS = ("cartpole:length=2.0", "cartpole:gravity=98.0", "cartpole:gravity=0.98")
# Detectors fitted on 3 episodes peak early in the 19 calibration episodes: the calibration says so
# (EarlyPeaksWarning, tested in tests/monitor/test_rule_and_calibration.py); not what these tests are about.
EARLY_PEAKS = pytest.mark.filterwarnings("ignore::oodmon.monitor.threshold.EarlyPeaksWarning")


def test_bench_end_to_end_and_resume(tmp_path):
    # 3 calibration episodes at a marginal far of 0.5 (the fewest that give a threshold): these tests
    # of the bench's machinery do not read the threshold's level, and 19 ID episodes cost seconds.
    config = BenchConfig("cartpole", ("dropout",), trials=2, variants=SPECS, episodes=2, id_episodes=3,
                         eval_episodes=2, calibration_episodes=3, far=0.5, confidence=None, out=str(tmp_path),
                         workers=2, train_steps=300)
    stages = []
    result = run_bench(config, on_progress=lambda stage, done, total: stages.append((stage, done, total)))
    logs_root = tmp_path / "logs" / f"cartpole-{config.cache_key()}"
    failing = json.loads((logs_root / "dropout/trial0/failing.json").read_text())
    assert failing["variants"] == list(SPECS)
    # The zoo agent survives gravity 0.98 and fails the other two.
    assert failing["failing"] == ["cartpole:length=2.0", "cartpole:gravity=98.0"]
    assert (tmp_path / "models/cartpole-dropout-trial1/model.json").exists()  # trial 1 was trained
    # Every row's AUROC is what replaying that trial's logs gives.
    for row in result.rows:
        for trial, auroc in row.aurocs.items():
            folder = logs_root / "dropout" / f"trial{trial}"
            logs = [read_log(p) for p in sorted(folder.glob("*.mcap"))]
            replayed = {m.variant: m.auroc for m in compute_metrics(logs)}
            assert replayed[row.variant] == auroc
    length = next(r for r in result.rows if r.variant == "cartpole:length=2.0")
    assert 0 in length.aurocs and length.paper is None  # the paper has no dropout length=2.0 trial
    # Each trial's ID return is its model's own: the zoo agent solves CartPole, a 300-step training does not.
    trained = json.loads((tmp_path / "models/cartpole-dropout-trial1/model.json").read_text())["id_return_mean"]
    assert result.id_returns == {"dropout": {0: 500.0, 1: trained}} and trained < 475
    assert unsolved_trials(result.id_returns, "cartpole") == [("dropout", 1, trained)]
    cells = [(done, total) for stage, done, total in stages if stage == "monitored cells"]
    assert cells[0][0] == 0 and cells[-1][0] == cells[-1][1] == 2 + 2 + len(result.failing["dropout"][1])
    # Run again: every cell is complete, nothing is recomputed.
    mtimes = {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.mcap")}
    again = run_bench(config)
    assert {p: p.stat().st_mtime_ns for p in tmp_path.rglob("*.mcap")} == mtimes
    assert [r.aurocs for r in again.rows] == [r.aurocs for r in result.rows]
    # New weights for trial 1 (a retrained or newly shipped model): its cached results are set
    # aside, not reused and not lost; trial 0's stay where they are.
    from safetensors.torch import save_file

    weights_file = tmp_path / "models/cartpole-dropout-trial1/model.safetensors"
    tensors = load_file(str(weights_file))
    save_file({k: v * 1.01 if v.is_floating_point() else v for k, v in tensors.items()}, str(weights_file))
    import hashlib

    metadata = json.loads((weights_file.parent / "model.json").read_text())  # as a retraining writes it
    metadata["safetensors_sha256"] = hashlib.sha256(weights_file.read_bytes()).hexdigest()
    (weights_file.parent / "model.json").write_text(json.dumps(metadata))
    trial1 = tmp_path / f"logs/cartpole-{config.cache_key()}/dropout/trial1"
    old_threshold = (trial1 / f"threshold-{config.cache_key()}.json").read_text()
    run_bench(config)
    set_aside = list((tmp_path / "set-aside").glob("weights-*/logs/cartpole-*/dropout/trial1/threshold-*.json"))
    assert len(set_aside) == 1 and set_aside[0].read_text() == old_threshold
    assert (trial1 / f"threshold-{config.cache_key()}.json").read_text() != old_threshold
    assert {p: p.stat().st_mtime_ns for p in (trial1.parent / "trial0").glob("*.mcap")} == {
        p: t for p, t in mtimes.items() if "trial0" in str(p)}


def test_the_threshold_cache_is_keyed_on_everything_that_makes_the_threshold(monkeypatch):
    """Changing far, the confidence, the calibration episodes, the window, the detectors (or how they
    are fitted) or the sensor noise must not reuse a threshold calibrated otherwise (it did for far
    and the episodes)."""
    base = BenchConfig("cartpole", ("dropout",), 1)
    keys = {base.cache_key()} | {BenchConfig("cartpole", ("dropout",), 1, **change).cache_key() for change in (
        {"far": 0.1}, {"calibration_episodes": 50}, {"window": 5}, {"score": "max_std"}, {"obs_noise": 0.01},
        {"confidence": None}, {"confidence": 0.8},
        {"detectors": ("spread", "dynamics")}, {"detectors": ("spread", "dynamics"), "alarm_detector": "dynamics"},
        {"masks": "fixed"}, {"masks": "sampled"}, {"warmup": 20})}
    assert len(keys) == 13  # sampled masks given is another key too: the model's own masks might be fixed
    # no warm-up is no setting, as results from before warm-ups existed say (their baselines still compare)
    assert "warmup" not in base.what_made_the_numbers()
    assert BenchConfig("cartpole", ("dropout",), 1, warmup=20).what_made_the_numbers()["warmup"] == 20
    with pytest.raises(ConfigError, match="masks='frozen'"):
        BenchConfig("cartpole", ("dropout",), 1, masks="frozen")
    one = {"sb3": ("runs/dqn0.zip",), "env_id": "CartPole-v1"}  # one user's model (with dropout): fixed masks are its own
    assert BenchConfig("cartpole", ("sb3",), 1, masks="fixed", **one).cache_key().endswith("-fixed-masks")
    with pytest.raises(ConfigError, match="one --sb3 model with dropout"):  # several models: members already
        BenchConfig("cartpole", ("sb3",), 1, masks="fixed", sb3=("runs/dqn0.zip", "runs/dqn1.zip"), env_id="CartPole-v1")
    # Learned detectors fitted by an older oodmon (another fitting version) are not reused either
    from oodmon.monitor.detectors import fitting

    learned = {"detectors": ("spread", "dynamics")}
    today = BenchConfig("cartpole", ("dropout",), 1, **learned).cache_key()
    assert today.endswith(f"-fit{fitting.FIT_VERSION}")
    monkeypatch.setattr(fitting, "FIT_VERSION", fitting.FIT_VERSION + 1)
    assert BenchConfig("cartpole", ("dropout",), 1, **learned).cache_key() != today
    assert BenchConfig("cartpole", ("dropout",), 1).cache_key() == base.cache_key()  # spread alone: nothing fitted
    # your own env's fits since its jumping readings became the dynamics model's inputs and drift
    # joined its default set (both 2026-11-29)
    own = BenchConfig("Acrobot-v1", ("sb3",), 1, sb3=("runs/a.zip",), env_id="Acrobot-v1", variants=("Acrobot-v1:dt=0.3",),
                      protocol="monitor", onsets=(20, 100), **learned).cache_key()
    assert own.endswith("-jump3-drift") and not today.endswith("-jump3-drift")
    # nor a combined of Pong's default set fitted before stillness joined it (2026-11-30); named
    # members, and CartPole's vectors, are what they were; nor any of Pong's fitted before its fits
    # took 90 whole games and vanishing joined its default set (2026-12-01)
    pong = {"detectors": ("spread", "combined"), "alarm_detector": "combined"}
    assert BenchConfig("pong", ("dropconnect",), 1, **pong).cache_key().endswith("-still-vanish")
    named = {"detectors": ("spread", "frames", "combined"), "alarm_detector": "combined"}
    named_key = BenchConfig("pong", ("dropconnect",), 1, **named).cache_key()
    assert named_key.endswith("-vanish") and "-still" not in named_key
    assert not BenchConfig("cartpole", ("dropout",), 1, **pong).cache_key().endswith(("-still", "-vanish"))
    # nor detectors fitted on another number of episodes (the key ignored it before)
    assert BenchConfig("cartpole", ("dropout",), 1, fit_episodes=60, **learned).cache_key() != \
        BenchConfig("cartpole", ("dropout",), 1, **learned).cache_key()
    # nor a dynamics model fitted with another cap of its updates (2026-12-02: --dynamics-updates);
    # the default is no setting, as results from before the option say; without a learned detector
    # it would shape nothing, and is refused
    from oodmon.monitor.detectors.dynamics import MAX_UPDATES

    assert BenchConfig("cartpole").dynamics_updates == MAX_UPDATES
    capped = {BenchConfig("cartpole", ("dropout",), 1, dynamics_updates=updates, **learned).cache_key()
              for updates in (MAX_UPDATES, 5000, 3000)}
    assert MAX_UPDATES is None and len(capped) == 3  # every epoch, since fitting version 9
    assert BenchConfig("cartpole", ("dropout",), 1, **learned).cache_key() in capped
    assert any(key.endswith("-updates3000") for key in capped)
    assert "dynamics_updates" not in BenchConfig("cartpole", ("dropout",), 1, **learned).what_made_the_numbers()
    assert BenchConfig("cartpole", ("dropout",), 1, dynamics_updates=3000, **learned
                       ).what_made_the_numbers()["dynamics_updates"] == 3000
    with pytest.raises(ConfigError, match="dynamics_updates shapes the fit of the learned detectors, and this bench "
                                          "fits none"):
        BenchConfig("cartpole", ("dropout",), 1, dynamics_updates=3000)
    with pytest.raises(ConfigError, match=r"^fit_episodes and dynamics_updates shape the fit of the learned detectors, "
                                          r"and this bench fits none \(detectors: spread\)"):
        BenchConfig("cartpole", ("dropout",), 1, fit_episodes=30, dynamics_updates=5000)
    with pytest.raises(ConfigError, match="dynamics_updates=0 is not allowed"):
        BenchConfig("cartpole", ("dropout",), 1, dynamics_updates=0, **learned)
    # nor detectors fitted on some random actions (2026-12-07: --fit-explore), alike
    explored = BenchConfig("cartpole", ("dropout",), 1, fit_explore=0.1, **learned)
    plain = BenchConfig("cartpole", ("dropout",), 1, **learned)
    assert explored.cache_key() == f"{plain.cache_key()}-explore0.1"
    assert explored.what_made_the_numbers()["fit_explore"] == 0.1 and "fit_explore" not in plain.what_made_the_numbers()
    with pytest.raises(ConfigError, match="^fit_explore shapes the fit of the learned detectors, and this bench fits"):
        BenchConfig("cartpole", ("dropout",), 1, fit_explore=0.1)
    with pytest.raises(ConfigError, match="^fit_explore=1.0 is not allowed"):
        BenchConfig("cartpole", ("dropout",), 1, fit_explore=1.0, **learned)
    # numpy's numbers from a Python caller are written as plain ones (a results file is JSON: before
    # 2026-12-07 it failed to write, after the bench's work)
    numbers = BenchConfig("cartpole", ("dropout",), 1, fit_explore=np.float32(0.5), dynamics_updates=np.int64(500),
                          warmup=np.int64(2), **learned).what_made_the_numbers()
    assert json.loads(json.dumps(numbers))["dynamics_updates"] == 500 and numbers["fit_explore"] == 0.5
    with pytest.raises(ConfigError, match="unknown detector 'sonar'"):
        BenchConfig("cartpole", detectors=("spread", "sonar"))
    # Too few calibration episodes for the bound is said before any work.
    with pytest.raises(ConfigError, match="far=0.05 needs at least 45 ID calibration episodes"):
        BenchConfig("cartpole", calibration_episodes=20)


def test_paper_labels_match_our_specs():
    assert paper_label("cartpole", "ensemble", "cartpole:gravity=98.0") == "gravity=98.0"
    assert paper_label("pendulum", "dropout", "pendulum:l=5.0") == "l=5.0"
    assert paper_label("pong", "dropconnect", "pong:motion_blur@4") == "motion_blur@4"
    assert paper_label("cartpole", "ensemble", "cartpole:gravity=0.98") is None
    # The paper's table says cart mass 3 where its text says pole mass: our masscart=3.0 is that row.
    assert paper_label("cartpole", "dropout", "cartpole:masscart=3.0").startswith("masspole_or_masscart=3.0")


def test_bench_cli_prints_our_numbers_beside_the_papers(tmp_path):
    result = run_cli("bench", "--task", "cartpole", "--methods", "ensemble", "--trials", "1",
                     "--variants", "cartpole:length=2.0", "--episodes", "2", "--id-episodes", "3", "--workers", "1",
                     "--calibration-episodes", "22", "--far", "0.1", "--out", str(tmp_path), "--json")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    row = report["rows"][0]
    assert row["variant"] == "cartpole:length=2.0" and row["method"] == "ensemble"
    assert row["paper"] == [0.862, 0.826, 0.993, 0.864, 0.87] and 0.0 <= row["mean"] <= 1.0
    assert np.isclose(row["mean"], row["aurocs"]["0"])
    # The tables (cells cached now) end with what the alarm rule did, as the JSON reports it.
    tables = run_cli("bench", "--task", "cartpole", "--methods", "ensemble", "--trials", "1",
                     "--variants", "cartpole:length=2.0", "--episodes", "2", "--id-episodes", "3", "--workers", "1",
                     "--calibration-episodes", "22", "--far", "0.1", "--out", str(tmp_path))
    assert tables.returncode == 0, tables.stderr
    detected = report["monitor"]["ensemble/trial0/cartpole:length=2.0"]["detection_rate"]
    alarm_row = next(line for line in tables.stdout.splitlines() if "│ length=2.0 " in line and "%" in line)
    assert f"{detected:.0%}" in alarm_row
    id_row = next(line for line in tables.stdout.splitlines() if "│ cartpole " in line)
    assert f"{report['monitor']['ensemble/trial0/cartpole']['false_alarm_rate']:.0%}" in id_row
    # How many shifted episodes failed (the pole fell: the env ended them), as the log has them.
    shifted = next(log for log in read_logs([tmp_path]) if log.episodes[0].variant == "cartpole:length=2.0")
    cell = report["monitor"]["ensemble/trial0/cartpole:length=2.0"]
    assert cell["episodes"] == 2 and cell["failed"] == sum(e.terminated for e in shifted.episodes)
    assert re.search(r"┃ +episodes failed ┃", tables.stdout)  # and the printed table says it beside the AUROC
    auroc_row = next(line for line in tables.stdout.splitlines() if "│ length=2.0 " in line and "±" in line)
    assert f"{cell['failed']} of 2" in auroc_row
    assert report["monitor"]["ensemble/trial0/cartpole"]["failed"] is None  # ID episodes: no shift to fail in


def test_best_per_method_ranks_each_methods_variants_by_their_best_trial():
    from oodmon.bench import BenchResult, Row

    rows = [Row("dropout", "cartpole:length=2.0", {0: 0.60, 1: 0.90}, None),
            Row("dropout", "cartpole:gravity=98.0", {0: 0.80, 1: 0.70}, [0.5, 0.75]),
            Row("ensemble", "cartpole:length=2.0", {0: 0.95}, [0.862, 0.993]),
            Row("ensemble", "cartpole:length=2.0", {0: 0.99}, None, "dynamics")]  # not the spread's
    assert best_per_method(BenchResult(rows, {}, {}), "cartpole", top=2) == [
        ("dropout", "cartpole:length=2.0", 0.90, None),
        ("dropout", "cartpole:gravity=98.0", 0.80, 0.75),
        ("ensemble", "cartpole:length=2.0", 0.95, 0.993),
    ]


def test_a_paper_report_without_the_spread_ranks_its_own_detector_and_shows_no_empty_paper_columns():
    # Your own policy gives no samples: its paper-protocol bench reads the dynamics detector, and the
    # paper has no figures for it. Before 2026-12-03 its best-AUROC table was empty (it ranked the
    # spread only) and both tables carried empty "paper" and "difference" columns.
    import io

    from rich.console import Console

    from oodmon.bench import BenchResult, Row, print_paper_report

    def printed(config, rows):
        buffer = io.StringIO()
        print_paper_report(config, BenchResult(rows, {}, {}), Console(file=buffer, width=200))
        return " ".join(buffer.getvalue().split())

    learned = BenchConfig(task="cartpole", methods=("plain",), trials=1, policy="my_controller:act", env_id="CartPole-v1",
                          detectors=("dynamics",), alarm_detector="dynamics", variants=("cartpole:length=2.0",))
    out = printed(learned, [Row("plain", "cartpole:length=2.0", {0: 0.996}, None, "dynamics")])
    assert "best single-trial AUROC per method, dynamics detector (the paper's main tables rank the spread)" in out
    assert "┃ method ┃ variant ┃ trials ┃ ours ┃" in out and "┃ method ┃ variant ┃ ours ┃" in out  # no paper columns
    assert "│ plain │ length=2.0 │ 1 │ 0.996 ± 0.000 │" in out and "│ plain │ length=2.0 │ 0.996 │" in out
    assert "beside the paper's" not in out and "difference" not in out
    spread = BenchConfig(task="cartpole", methods=("ensemble",), variants=("cartpole:length=2.0",))
    out = printed(spread, [Row("ensemble", "cartpole:length=2.0", {0: 0.95}, [0.862, 0.993])])
    assert "ours (mean ± std over trials) beside the paper's" in out
    assert "│ ensemble │ length=2.0 │ 0.950 │ 0.993 │ -0.043 │" in out
    assert "best single-trial AUROC per method (the paper's main tables)" in out


def test_a_paper_report_of_every_trial_says_how_many_of_a_rows_trials_fail():
    """``--all-variants`` under the paper's protocol scores every trial on every variant, whether or
    not it fails there (the paper scored its five trials on the variants its trained model failed
    on): the table says so, and per row how many of the trials it averages fail."""
    import io

    from rich.console import Console

    from oodmon.bench import BenchResult, Row, print_paper_report

    named = ("cartpole:length=2.0", "cartpole:gravity=98.0")
    rows = [Row("ensemble", named[0], {0: 0.99, 1: 0.93}, [0.862, 0.993]),
            Row("ensemble", named[1], {0: 0.95, 1: 0.97}, [0.756, 0.833])]
    failing = {"ensemble": {0: [named[0]], 1: []}}

    def printed(all_variants):
        buffer = io.StringIO()
        config = BenchConfig(task="cartpole", methods=("ensemble",), trials=2, variants=named, all_variants=all_variants)
        print_paper_report(config, BenchResult(rows, failing, {}), Console(file=buffer, width=200))
        return " ".join(buffer.getvalue().split())

    out = printed(True)
    assert "per-step AUROC per variant, every trial scored (--all-variants)" in out
    assert "│ ensemble │ length=2.0 │ 2 scored, 1 fails │ 0.960 ± 0.030 │" in out
    assert "│ ensemble │ gravity=98.0 │ 2 scored, none fail │ 0.960 ± 0.010 │" in out
    out = printed(False)  # (rows of trials that failed, as the bench scores them without the flag)
    assert "per-step AUROC per failing variant" in out and "│ ensemble │ length=2.0 │ 2 │ 0.960 ± 0.030 │" in out


def test_alarms_are_averaged_over_the_trials_that_have_them():
    from oodmon.bench import BenchResult, alarms_per_variant

    detection = {
        "dropout/trial0/cartpole": {"false_alarm_rate": 0.0, "detection_rate": None, "delay_mean": None},
        "dropout/trial1/cartpole": {"false_alarm_rate": 0.5, "detection_rate": None, "delay_mean": None},
        "dropout/trial0/cartpole:length=2.0": {"false_alarm_rate": None, "detection_rate": 1.0, "delay_mean": 10.0},
        "dropout/trial1/cartpole:length=2.0": {"false_alarm_rate": None, "detection_rate": 0.0, "delay_mean": None},
    }
    assert alarms_per_variant(BenchResult([], {}, detection)) == [
        ("dropout", "cartpole", 0.25, None, None),
        ("dropout", "cartpole:length=2.0", None, 0.5, 10.0),
    ]


@pytest.mark.slow
def test_ray_executor_on_a_loopback_cluster_gives_the_same_models_and_numbers_as_local_processes(tmp_path, monkeypatch):
    """One Ray cluster (starting one is most of this test's time): the bench's ``_start_ray`` starts
    it listening on 127.0.0.1 only, a bench on a cluster already running uses it and leaves it
    running; a trial's training runs there as a task (before: in the bench's own process), to the
    weights a local training of its seed gives, byte for byte, its progress reaching the bench's
    report; and its cells give the numbers local processes give."""
    import ray

    from oodmon.bench.cells import _start_ray
    from tests.monitor.test_sinks import _listening

    common = dict(task="cartpole", methods=("dropout",), trials=2, variants=("cartpole:length=2.0",), episodes=2,
                  id_episodes=2, eval_episodes=2, calibration_episodes=3, far=0.5, confidence=None, workers=1,
                  train_steps=300)
    local = run_bench(BenchConfig(**common, out=str(tmp_path / "local")))
    before = _listening()
    on_ray_config = BenchConfig(**common, out=str(tmp_path / "ray"), executor="ray")
    sigterm = signal.getsignal(signal.SIGTERM)
    started = _start_ray(on_ray_config, workers=1)
    # ray.init sets a SIGTERM handler that exits (sys.exit(15)), and its core a C++ one: the bench's stop
    # said nothing of what it kept and ended with 1 (2026-12-06); _start_ray puts back the one before
    assert signal.getsignal(signal.SIGTERM) is sigterm
    stages = []

    def not_here(*_, **__):
        raise AssertionError("a trial trained in the bench's own process, not on the cluster")

    monkeypatch.setattr("oodmon.bench.cache.train", not_here)  # (the cluster's workers import their own)
    try:
        new = _listening() - before
        assert started and new and {address for address, _ in new} == {"127.0.0.1"}
        assert ray.nodes()[0]["NodeManagerAddress"] == "127.0.0.1"
        on_ray = run_bench(on_ray_config, on_progress=lambda *report: stages.append(report))
        assert ray.is_initialized()  # not the bench's cluster: not the bench's to shut down
    finally:
        ray.shutdown()
    assert [s for s in stages if s[0] == "trained trial models"] == [("trained trial models", d, 1) for d in (0, 1)]
    steps = [s for s in stages if s[0] == "dropout trial 1: main training steps"]  # the training's own, from its task
    assert steps and steps[-1][1] >= steps[-1][2], stages
    model = "models/cartpole-dropout-trial1/model.safetensors"
    assert (tmp_path / "ray" / model).read_bytes() == (tmp_path / "local" / model).read_bytes()
    assert [r.aurocs for r in on_ray.rows] == [r.aurocs for r in local.rows]
    assert on_ray.rows and 0.0 <= on_ray.rows[0].mean <= 1.0
    key = BenchConfig(**common).cache_key()
    assert sorted(p.name for p in (tmp_path / f"ray/logs/cartpole-{key}/dropout/trial0").glob("*.mcap")) == [
        "cartpole.mcap", "cartpole_length_2.0.mcap"]


def test_bench_never_starts_hours_of_pong_training_and_says_how_instead(tmp_path):
    config = BenchConfig(task="pong", methods=("dropconnect", "dropout"), trials=2, out=str(tmp_path))
    with pytest.raises(ConfigError) as error:
        run_bench(config)
    message = str(error.value)
    # The first missing model is named with the command that trains it; nothing was run before.
    assert "no pong dropconnect model for trial 1" in message
    assert f"oodmon train --task pong --method dropconnect --seed 1 --out {tmp_path}/models/pong-dropconnect-trial1" in message
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("detectors, masks, why", [
    (("spread", "scaled_spread"), None, "the dropout agents cannot have every detector asked for: the scaled_spread "
                                        "detector puts each ensemble member's values on its own ID footing"),
    (("spread", "frames"), "fixed", "the dropout agents cannot have every detector asked for: the frames detector needs "
                                    "image observations; this env's are of shape (4,)"),
    (("spread", "transitions"), None, "the transitions detector counts states that repeat (discrete observations); "
                                      "cartpole's are continuous readings")], ids=["scaled_spread", "frames", "transitions"])
def test_a_detector_the_agents_cannot_have_is_refused_before_the_trainings(tmp_path, detectors, masks, why):
    """Refused when trial 0's detectors were fitted, after the other trials' models had trained;
    now before anything is trained. With fixed masks, the Dropout agents have scaled_spread."""
    config = BenchConfig(task="cartpole", methods=("dropout",), trials=2, detectors=detectors, masks=masks,
                         out=str(tmp_path))
    with pytest.raises(ConfigError, match=re.escape(why)):
        run_bench(config)
    assert not any(tmp_path.iterdir())  # no model trained, nothing written


def test_paper_variants_without_our_auroc_are_only_those_the_bench_ran():
    from oodmon.bench import BenchResult, Row, paper_only_variants

    result = BenchResult([Row("ensemble", "cartpole:length=2.0", {0: 0.85}, None)], {}, {})
    # The paper reports gravity=98.0 and length=2.0 for the ensemble; we have length=2.0.
    assert paper_only_variants(result, "cartpole", ["ensemble"]) == [("ensemble", "gravity=98.0", 0.833)]
    assert paper_only_variants(result, "cartpole", ["ensemble"], ran=["cartpole:length=2.0"]) == []
    ran = ["cartpole:length=2.0", "cartpole:gravity=98.0"]
    assert [label for _, label, _ in paper_only_variants(result, "cartpole", ["ensemble"], ran=ran)] == ["gravity=98.0"]


def test_variants_no_trial_failed_on_are_named_not_dropped_in_silence():
    from rich.console import Console

    from oodmon.bench import BenchConfig, BenchResult, unfailed_variants
    from oodmon.bench.report import print_unfailed

    named = ("cartpole:length=2.0", "cartpole:gravity=78.4", "cartpole:masscart=9.0")
    # Trial 0 fails on length=2.0, trial 1 on gravity=78.4: only masscart=9.0 was failed by neither.
    failing = {"ensemble": {0: ["cartpole:length=2.0"], 1: ["cartpole:gravity=78.4"]}, "dropout": {0: [], 1: []}}
    result = BenchResult([], failing, {})
    config = BenchConfig(task="cartpole", methods=("ensemble", "dropout"), trials=2, variants=named)
    assert unfailed_variants(config, result) == {"ensemble": ["cartpole:masscart=9.0"], "dropout": list(named)}
    console = Console(record=True, width=400)
    print_unfailed(config, result, console)
    line = console.export_text()
    assert "not scored" in line and "ensemble cartpole:masscart=9.0, dropout cartpole:length=2.0" in line
    # The monitor's protocol says "monitored"; the paper's grid gets counts, not 90 names.
    console = Console(record=True, width=400)
    print_unfailed(BenchConfig(task="cartpole", methods=("ensemble",), trials=2, protocol="monitor", variants=named),
                   result, console)
    assert "not monitored" in console.export_text()
    console = Console(record=True, width=400)
    print_unfailed(BenchConfig(task="cartpole", methods=("ensemble",), trials=2), result, console)
    assert "ensemble 88 of 90" in console.export_text()
    # With --all-variants every variant is run, so nothing is left out.
    assert unfailed_variants(BenchConfig(task="cartpole", variants=named, all_variants=True), result) == {}


@EARLY_PEAKS
def test_bench_reports_every_detector_as_replaying_its_logs_gives(tmp_path):
    """--detectors: learned detectors fitted per trial (cached), every cell logs every score, and each
    row's AUROC is what replaying the logs gives for that detector; the alarm reads the one named."""
    config = BenchConfig("cartpole", ("ensemble",), 1, ("cartpole:length=2.0",), episodes=2, id_episodes=2,
                         eval_episodes=1, calibration_episodes=19, confidence=None, out=str(tmp_path), workers=1,
                         detectors=("spread", "dynamics", "combined"), alarm_detector="dynamics", fit_episodes=3)
    result = run_bench(config)
    assert [r.detector for r in result.rows] == ["spread", "dynamics", "combined"]
    folder = tmp_path / "logs" / f"cartpole-{config.cache_key()}" / "ensemble" / "trial0"
    assert (folder / f"detectors-{config.cache_key()}" / "detectors.json").exists()
    assert json.loads((folder / f"threshold-{config.cache_key()}.json").read_text())["detector"] == "dynamics"
    logs = [read_log(p) for p in sorted(folder.glob("*.mcap"))]
    for row in result.rows:
        replayed = {m.variant: m.auroc for m in compute_metrics(logs, row.detector)}
        assert replayed["cartpole:length=2.0"] == row.aurocs[0]
    assert result.rows[1].aurocs[0] > 0.9  # dynamics sees the longer pole (measured 0.99-1.00)
    # scripts/member_excursions.py ranks each member as the logged combined score did: per episode,
    # the combined score's largest value is the largest of its members' (and dynamics' mean's)
    from oodmon.monitor.detectors import DetectorSet

    fitted = DetectorSet.load(folder / f"detectors-{config.cache_key()}")
    assert result.fitted == {"ensemble": {0: fitted.fingerprints()}}  # what --baseline compares (below)
    assert set(result.fitted["ensemble"][0]) == {"dynamics", "combined"}
    combined = fitted["combined"]
    for name in ("cartpole", "cartpole_length_2.0"):
        maxima = load_script("member_excursions")[1].episode_maxima(combined, folder / f"{name}.mcap", after_onset=False)
        assert set(maxima) == {"spread", "dynamics", "dynamics mean"}
        logged = [episode.detector_scores["combined"].max() for episode in read_log(folder / f"{name}.mcap").episodes]
        np.testing.assert_allclose(np.max(list(maxima.values()), axis=0), logged, rtol=0, atol=1e-9)


@EARLY_PEAKS
def test_the_monitors_protocol_shifts_each_episode_at_its_own_onset_and_replays_the_alarms(tmp_path):
    """--protocol monitor: onsets drawn per episode from its seed, logs apart from the paper's
    protocol's (which shares the threshold and the detectors), alarm figures equal to replaying the logs."""
    from dataclasses import replace

    from oodmon import seeds
    from oodmon.bench import ONSETS, episode_onset
    from oodmon.replay import compute_monitor_metrics

    config = BenchConfig("cartpole", ("ensemble",), 1, ("cartpole:length=2.0",), episodes=4, id_episodes=3,
                         eval_episodes=1, calibration_episodes=19, confidence=None, out=str(tmp_path), workers=1,
                         detectors=("spread", "dynamics"), alarm_detector="dynamics", fit_episodes=3,
                         protocol="monitor")
    result = run_bench(config)
    folder = tmp_path / "logs" / f"cartpole-{config.cache_key()}" / "ensemble" / "trial0"
    threshold_file = folder / f"threshold-{config.cache_key()}.json"
    assert json.loads(threshold_file.read_text())["consecutive"] == 1  # a learned detector's default m
    logs = [read_log(p) for p in sorted((folder / "monitor").glob("*.mcap"))]
    shifted = [e for log in logs for e in log.episodes if e.variant != "cartpole"]
    onsets = [e.onset for e in shifted]
    assert onsets == [episode_onset(ONSETS["cartpole"], seeds.BENCH_SHIFTED + k) for k in range(4)]
    assert len(set(onsets)) > 1 and all(20 <= onset < 200 for onset in onsets)
    assert all(not e.shifted[: e.onset + 1].any() and e.shifted[e.onset + 1:].all() for e in shifted)
    assert all(e.rewards is not None and e.terminated is not None for log in logs for e in log.episodes)
    assert result.alarms == compute_monitor_metrics(logs)
    (row,) = [m for m in result.alarms if m.variant == "cartpole:length=2.0"]
    # Even fitted on 3 episodes, dynamics alarms in every shifted episode, before the pole falls.
    assert row.alarmed == 4 and row.failed >= 1 and row.before_failure == row.failed
    assert sorted(row.delays) == sorted(e.alarm.nonzero()[0][0] - e.onset for e in shifted)
    # The paper's protocol reuses the threshold and writes its logs beside, not over, these.
    before = threshold_file.stat().st_mtime_ns
    run_bench(replace(config, protocol="paper"))
    assert threshold_file.stat().st_mtime_ns == before
    assert sorted(p.name for p in folder.glob("*.mcap")) == ["cartpole.mcap", "cartpole_length_2.0.mcap"]


def test_the_same_bench_calibrates_the_same_threshold_for_an_mc_agent(tmp_path):
    """The trial's agent samples with a fixed seed: two benches, the same threshold file (an MC
    Dropout agent's threshold used to vary from run to run)."""
    common = dict(task="cartpole", methods=("dropout",), trials=1, variants=("cartpole:length=2.0",), episodes=1,
                  id_episodes=1, eval_episodes=1, calibration_episodes=3, far=0.5, confidence=None, workers=1)
    thresholds = []
    for name in ("a", "b"):
        config = BenchConfig(**common, out=str(tmp_path / name))
        run_bench(config)
        path = tmp_path / name / "logs" / f"cartpole-{config.cache_key()}" / "dropout" / "trial0"
        thresholds.append(json.loads((path / f"threshold-{config.cache_key()}.json").read_text()))
    assert thresholds[0] == thresholds[1] and thresholds[0]["method"] == "dropout"


def test_a_bench_stopped_between_its_stages_resumes_drawing_what_an_uninterrupted_one_draws(tmp_path, monkeypatch):
    """An MC agent's fitting, calibration and evaluation draw from one seeded generator in turn.
    A bench that stopped after a stage (its output cached, the rest not) must set the sampling back
    to where it stood after that stage: before, the evaluation of a resumed bench began from the
    fresh seed, so which variants an MC agent fails on depended on where an earlier run had stopped."""
    from oodmon.bench import cache

    states = []
    real_evaluate = cache.evaluate_variants

    def recording_evaluate(act, *args, **kwargs):
        states.append(act.__self__.estimator.sampling_state)  # where the sampling stands as evaluation begins
        return real_evaluate(act, *args, **kwargs)

    monkeypatch.setattr(cache, "evaluate_variants", recording_evaluate)
    config = BenchConfig("cartpole", ("dropout",), 1, ("cartpole:length=2.0",), episodes=1, id_episodes=1,
                         eval_episodes=1, calibration_episodes=19, confidence=None, out=str(tmp_path), workers=1,
                         detectors=("spread", "dynamics"), alarm_detector="dynamics", fit_episodes=3)
    folder = tmp_path / "logs" / f"cartpole-{config.cache_key()}" / "dropout" / "trial0"
    threshold_file = folder / f"threshold-{config.cache_key()}.json"

    def prepare():
        cache._prepare_trial(config, "dropout", 0, lambda *_: None)
        return threshold_file.read_text(), (folder / "failing.json").read_text()

    uninterrupted = prepare()
    (folder / "failing.json").unlink()  # stopped after calibrating
    assert prepare() == uninterrupted and states[1] == states[0]
    threshold_file.unlink()  # stopped after fitting: calibration again from where fitting left the sampling
    (folder / "failing.json").unlink()
    assert prepare() == uninterrupted and states[2] == states[0]
    # The same from a fresh seed would have drawn otherwise: the evaluation began elsewhere, the
    # dropout agent's threshold came out otherwise.
    threshold_file.unlink()
    (folder / "failing.json").unlink()
    for state in folder.glob("sampling-after-*.json"):
        state.unlink()
    assert prepare()[0] != uninterrupted[0] and states[3] != states[0]


@EARLY_PEAKS
def test_one_trial_of_an_agent_that_draws_nothing_is_prepared_side_by_side_with_the_same_result(tmp_path, monkeypatch):
    """``--trials 1`` of one method: its fitting's, calibration's and evaluation's episodes are
    played by ``workers`` processes where the agent draws nothing (an ensemble), giving the detectors,
    threshold and failing variants of one process; an MC agent's stay in one process, so that its
    trial is what it is when prepared beside others (its episodes side by side would draw otherwise)."""
    import oodmon.monitor
    from oodmon.bench.run import _prepare_trials

    played_by = []
    real_calibrate = oodmon.monitor.calibrate_agent
    monkeypatch.setattr(oodmon.monitor, "calibrate_agent",
                        lambda *args, **kwargs: played_by.append(kwargs["workers"]) or real_calibrate(*args, **kwargs))
    prepared = {}
    runs = [("ensemble", None, 1), ("ensemble", None, 2), ("dropout", None, 2), ("dropout", "fixed-decisions", 1),
            ("dropout", "fixed-decisions", 2)]
    for method, masks, workers in runs:
        config = BenchConfig("cartpole", (method,), 1, SPECS[:2], episodes=1, id_episodes=1, eval_episodes=1,
                             calibration_episodes=3, far=0.5, confidence=None, workers=workers,
                             out=str(tmp_path / f"{method}{masks}{workers}"), detectors=("spread", "features"),
                             alarm_detector="features", fit_episodes=3, masks=masks)
        _, threshold, failing, detectors = _prepare_trials(config, [(method, 0)], workers, lambda *_: None)[(method, 0)]
        saved = json.loads(threshold.read_text())
        prepared[(method, masks, workers)] = (saved["value"], saved["detectors_hash"], failing,
                                              (detectors / "detectors.safetensors").read_bytes())
        assert saved["workers"] == played_by[-1]
    # The sampled dropout agent draws its samples: one process; its fixed sub-networks that decide draw nothing.
    assert played_by == [1, 2, 1, 1, 2]
    assert prepared[("ensemble", None, 2)] == prepared[("ensemble", None, 1)]
    assert prepared[("ensemble", None, 1)][2] == ["cartpole:length=2.0", "cartpole:gravity=98.0"]
    assert prepared[("dropout", "fixed-decisions", 2)] == prepared[("dropout", "fixed-decisions", 1)]


def test_pong_alarms_on_200_decision_means_of_features_and_on_each_step_of_combined(monkeypatch, tmp_path):
    """The CLI's window default per task and detector (oodmon.monitor.alarms.default_window), as
    bench passes it; Pong's default detector is combined (of frames, stillness and vanishing), and frames
    alone is read at each step too. And --fit-episodes, as bench passes it."""
    import oodmon.bench
    from oodmon.cli import main

    configs = []

    def record(config, on_progress=None):
        configs.append(config)
        raise SystemExit(0)  # the configuration is what is checked; nothing runs

    monkeypatch.setattr(oodmon.bench, "run_bench", record)
    common = ["--methods", "ensemble", "--trials", "1", "--protocol", "monitor", "--out", str(tmp_path / "b")]
    for argv, window, alarm in ((["--task", "pong"], 1, "combined"),
                                (["--task", "pong", "--alarm-detector", "features"], 200, "features"),
                                (["--task", "pong", "--alarm-detector", "frames"], 1, "frames"),
                                (["--task", "pong", "--window", "7"], 7, "combined"), (["--task", "cartpole"], 1, "combined")):
        with pytest.raises(SystemExit):
            main(["bench", *argv, *common])
        assert (configs[-1].window, configs[-1].alarm_detector) == (window, alarm)
    # --fit-episodes reaches the config (and its cache key); without it, the task's default (0 here)
    assert configs[-1].fit_episodes == 0
    with pytest.raises(SystemExit):
        main(["bench", "--task", "cartpole", "--fit-episodes", "60", *common])
    assert configs[-1].fit_episodes == 60 and configs[-1].cache_key().endswith("-on60")


def test_bench_results_are_data_and_a_later_bench_is_checked_against_them(tmp_path):
    """--results writes per-trial AUROC, AUPR and FPR@95 with the settings and command; --baseline
    passes an identical rerun, names a figure that fell, and refuses a baseline made otherwise."""
    common = ("bench", "--task", "cartpole", "--methods", "ensemble", "--trials", "1", "--variants",
              "cartpole:length=2.0,cartpole:gravity=98.0", "--episodes", "2", "--id-episodes", "3", "--workers", "1",
              "--calibration-episodes", "22", "--far", "0.1", "--out", str(tmp_path / "bench"))
    saved = tmp_path / "results" / "cartpole.json"
    first = run_cli(*common, "--results", str(saved))
    assert first.returncode == 0, first.stderr
    data = json.loads(saved.read_text())
    assert data["command"].startswith("oodmon bench --task cartpole") and data["config"]["far"] == 0.1
    assert data["id_returns"] == {"ensemble": {"0": 500.0}}  # the zoo agent's, from its model.json
    logs = [read_log(p) for p in sorted((tmp_path / "bench" / "logs").rglob("trial0/*.mcap"))]
    replayed = {m.variant: m for m in compute_metrics(logs)}
    for row in data["rows"]:
        m = replayed[row["variant"]]
        assert (row["aurocs"]["0"], row["auprs"]["0"], row["fprs"]["0"]) == (m.auroc, m.aupr, m.fpr_at_95_tpr)
        assert row["aupr_mean"] == m.aupr and row["fpr95_mean"] == m.fpr_at_95_tpr

    again = run_cli(*common, "--baseline", str(saved))  # the same cached cells: every figure holds
    assert again.returncode == 0, again.stderr
    assert "every figure of" in again.stderr
    # a baseline of more methods than this run: their rows are not compared, a row of its own method is
    more = dict(data, config=dict(data["config"], methods=["dropout", "ensemble"]),
                rows=data["rows"] + [dict(data["rows"][0], method="dropout", mean=1.0)])
    (tmp_path / "more.json").write_text(json.dumps(more))
    some = run_cli(*common, "--baseline", str(tmp_path / "more.json"))
    assert some.returncode == 0 and "rows of dropout not compared (not run: --methods ensemble)" in some.stderr
    more["rows"][0] = dict(more["rows"][0], mean=more["rows"][0]["mean"] + 0.05)  # the ensemble's row: compared
    (tmp_path / "more.json").write_text(json.dumps(more))
    some = run_cli(*common, "--baseline", str(tmp_path / "more.json"))
    assert some.returncode == 1 and sum(line.startswith("FELL ensemble/") for line in some.stderr.splitlines()) == 1
    assert "FELL dropout" not in some.stderr

    raised = json.loads(saved.read_text())
    row = raised["rows"][0]
    row["mean"] += 0.05  # a baseline better than this run by more than the tolerance
    raised["rows"].append(dict(row, variant="cartpole:masspole=9.0"))  # and a row this run lacks
    (tmp_path / "raised.json").write_text(json.dumps(raised))
    fell = run_cli(*common, "--baseline", str(tmp_path / "raised.json"))
    assert fell.returncode == 1
    falls = [line for line in fell.stderr.splitlines() if line.startswith("FELL")]
    assert len(falls) == 2, fell.stderr
    assert any(f"ensemble/{row['variant']}/spread: auroc fell from" in line for line in falls)
    assert any("cartpole:masspole=9.0/spread: missing from this bench" in line for line in falls)
    assert "other weights" not in fell.stderr and "records neither" not in fell.stderr  # the zoo agent's, as there
    from oodmon.agents import zoo_dir
    from oodmon.hashing import file_sha256

    shipped = file_sha256(zoo_dir() / "cartpole-ensemble" / "model.safetensors")
    assert data["weights"] == {"ensemble": {"0": shipped}}
    from oodmon.versions import machine

    assert data["machine"] == machine()
    # a baseline of other weights (a model retrained, or on a CPU that rounds otherwise): the falls say so
    (tmp_path / "retrained.json").write_text(json.dumps(dict(raised, weights={"ensemble": {"0": "f" * 64}})))
    retrained = run_cli(*common, "--baseline", str(tmp_path / "retrained.json"))
    assert retrained.returncode == 1
    assert f"numbers are of other weights: ensemble trial 0 ({'f' * 12} there, {shipped[:12]} here)" in retrained.stderr
    assert data["fitted"] == {"ensemble": {"0": {}}}  # spread alone: nothing fitted (fits: the test above, and below)
    (tmp_path / "old.json").write_text(json.dumps({k: v for k, v in raised.items() if k not in ("weights", "fitted")}))
    old = run_cli(*common, "--baseline", str(tmp_path / "old.json"))  # written before results held them
    assert old.returncode == 1 and "records neither its weights' sha256 nor its fits'" in old.stderr

    other = dict(data, config=dict(data["config"], far=0.05))
    (tmp_path / "other.json").write_text(json.dumps(other))
    refused = run_cli(*common, "--baseline", str(tmp_path / "other.json"))
    assert refused.returncode == 2 and "far 0.05 there, 0.1 here" in refused.stderr
    (tmp_path / "other.json").write_text(json.dumps(dict(data, config=dict(data["config"], methods=["dropout"]))))
    refused = run_cli(*common, "--baseline", str(tmp_path / "other.json"))  # a method the baseline lacks
    assert refused.returncode == 2 and "methods ['dropout'] there, ['ensemble'] here" in refused.stderr
    elsewhere = [a if a != str(tmp_path / "bench") else str(tmp_path / "fresh") for a in common]
    refused = run_cli(*elsewhere, "--baseline", str(tmp_path / "other.json"))
    assert refused.returncode == 2 and not (tmp_path / "fresh" / "logs").exists()  # refused before any work
    no_baseline = run_cli(*common, "--tolerance", "0.1")
    assert no_baseline.returncode == 2 and "--tolerance" in no_baseline.stderr
    not_a_result = run_cli(*common, "--baseline", str(tmp_path / "results"))
    assert not_a_result.returncode == 2 and "is a folder" in not_a_result.stderr


def test_a_trial_model_trained_by_another_recipe_is_set_aside_and_trained_again(tmp_path, capsys):
    """The bench's trained trials are cached; a cached one made by another recipe (here the
    shipped 50,000-step recipe, where this bench asks for 300 steps) is not silently reused."""
    import shutil

    from oodmon.agents import zoo_dir
    from oodmon.bench.cache import _ensure_model

    config = BenchConfig("cartpole", ("dropout",), trials=2, out=str(tmp_path), train_steps=300)
    cached = tmp_path / "models" / "cartpole-dropout-trial1"
    shutil.copytree(zoo_dir() / "cartpole-dropout", cached)
    shipped_weights = (cached / "model.safetensors").read_bytes()
    assert _ensure_model(config, "dropout", 1) == cached
    said = capsys.readouterr().err
    assert "trained by another recipe" in said and "learning_starts: 1000 -> 75" in said
    aside = tmp_path / "set-aside" / "recipe-0" / "models" / "cartpole-dropout-trial1"
    assert (aside / "model.safetensors").read_bytes() == shipped_weights  # kept, not deleted
    assert json.loads((cached / "model.json").read_text())["recipe_steps"] == 300
    retrained = (cached / "model.safetensors").read_bytes()
    assert _ensure_model(config, "dropout", 1) == cached  # its own recipe's model stays
    assert (cached / "model.safetensors").read_bytes() == retrained and "another recipe" not in capsys.readouterr().err


def test_an_unfinished_training_of_another_recipe_is_set_aside_too(tmp_path, capsys):
    """A trial folder holding a training begun by another recipe, killed before its model.json,
    is set aside (its runs' state.json record the recipe), not resumed as today's."""
    from oodmon.agents.recipes import recipe_record
    from oodmon.agents.recipes import recipe_for
    from oodmon.bench.cache import _ensure_model_dir_current

    config = BenchConfig("cartpole", ("dropout",), trials=2, out=str(tmp_path), train_steps=300)
    begun = tmp_path / "models" / "cartpole-dropout-trial1"
    (begun / "runs" / "main").mkdir(parents=True)
    state = {"steps": 20_000, "wall_time_s": 30.0, "finished": False, "seed": 1,
             "recipe": recipe_record(recipe_for("cartpole", "dropout"))}  # the 50,000-step recipe
    (begun / "runs" / "main" / "state.json").write_text(json.dumps(state))
    assert _ensure_model_dir_current(config, "dropout", 1) == begun and not begun.exists()
    said = capsys.readouterr().err
    assert "trained by another recipe" in said and "recipe_steps: 50000 -> 300" in said
    aside = tmp_path / "set-aside" / "recipe-0" / "models" / "cartpole-dropout-trial1" / "runs" / "main" / "state.json"
    assert json.loads(aside.read_text()) == state
    # the same recipe's unfinished training stays, to be resumed
    state["recipe"] = recipe_record(recipe_for("cartpole", "dropout").shortened(300))
    (begun / "runs" / "main").mkdir(parents=True)
    (begun / "runs" / "main" / "state.json").write_text(json.dumps(state))
    assert _ensure_model_dir_current(config, "dropout", 1) == begun and begun.exists()


def test_trial_models_train_on_every_worker_and_come_out_as_one_at_a_time(tmp_path):
    """The trials' trainings run in parallel processes; each model is the one a sequential
    training of the same seed makes (byte for byte), and progress counts the trainings."""
    from oodmon.bench.run import _train_missing_models

    trials = [("dropout", 1), ("dropout", 2)]
    weights = {}
    for workers in (2, 1):
        config = BenchConfig("cartpole", ("dropout",), trials=3, out=str(tmp_path / f"w{workers}"), train_steps=300,
                             workers=workers)
        stages = []
        _train_missing_models(config, trials, workers, lambda stage, done, total: stages.append((stage, done, total)))
        counted = [s for s in stages if s[0] == "trained trial models"]
        assert counted == [("trained trial models", 0, 2), *[("trained trial models", d, 2) for d in (1, 2)]]
        for trial in (1, 2):  # each training's own progress reaches the bench's report, named by its trial
            steps = [s for s in stages if s[0] == f"dropout trial {trial}: main training steps"]
            assert steps and steps[-1][1] >= steps[-1][2], stages  # (SB3 trains in chunks of train_freq)
        weights[workers] = [(tmp_path / f"w{workers}/models/cartpole-dropout-trial{t}/model.safetensors").read_bytes()
                            for _, t in trials]
        stages.clear()
        _train_missing_models(config, trials, workers, lambda *a: stages.append(a))
        assert stages == []  # cached: nothing to train
    assert weights[2] == weights[1] and weights[2][0] != weights[2][1]


def _in_worker_noting_its_process(*args):
    """The bench's ``_in_worker``, noting first the id of the process it runs in (in the file
    ``OODMON_TEST_PIDS`` names)."""
    import os

    with open(os.environ["OODMON_TEST_PIDS"], "a") as pids:
        pids.write(f"{os.getpid()}\n")
    return _bench_in_worker(*args)


def test_trials_are_prepared_side_by_side_in_workers_to_what_one_after_the_other_gives(tmp_path, monkeypatch):
    """Each trial's detectors, threshold and failing variants are made in a worker process of its
    own (they were made one after the other in the bench's process): the same files and figures
    as one after the other, each worker's progress reaching the bench's report."""
    import os

    import oodmon.bench.run as bench_run

    where = tmp_path / "pids"
    monkeypatch.setenv("OODMON_TEST_PIDS", str(where))
    monkeypatch.setattr(bench_run, "_in_worker", _in_worker_noting_its_process)  # (found by its name there)
    common = dict(task="cartpole", methods=("dropout", "ensemble"), trials=1, variants=("cartpole:length=2.0",),
                  episodes=2, id_episodes=2, eval_episodes=2, calibration_episodes=3, far=0.5, confidence=None)
    results, stages = {}, []
    for workers in (2, 1):
        config = BenchConfig(**common, workers=workers, out=str(tmp_path / f"w{workers}"))
        results[workers] = run_bench(config, on_progress=lambda *report: stages.append((workers, *report)))
    pids = where.read_text().split()
    assert len(pids) == 2 and str(os.getpid()) not in pids  # two trials in workers; one worker: here, no worker
    stage = "models, detectors, thresholds and failing variants of trials"
    assert [s[2:] for s in stages if s[0] == 2 and s[1] == stage] == [(0, 2), (1, 2), (2, 2)]
    assert any(s[0] == 2 and s[1] == "ensemble trial 0: calibration episodes" for s in stages)
    assert results[2].detection == results[1].detection and results[2].rows == results[1].rows
    for method in ("dropout", "ensemble"):
        made = [sorted((tmp_path / f"w{w}/logs").glob(f"*/{method}/trial0/threshold-*.json")) for w in (2, 1)]
        assert made[0] and [json.loads(f.read_text())["value"] for f in made[0]] == [
            json.loads(f.read_text())["value"] for f in made[1]]


def test_episode_noise_plays_a_benchs_trials_again_with_more_episodes(tmp_path, monkeypatch):
    """scripts/episode_noise.py: its first episodes are the bench's own (the file's AUROC, checked),
    the rest give the trial's AUROC over more episodes and the noise of the bench's few."""
    common = ("bench", "--task", "cartpole", "--methods", "ensemble", "--trials", "1", "--variants",
              "cartpole:length=2.0", "--episodes", "2", "--id-episodes", "3", "--workers", "1",
              "--calibration-episodes", "22", "--far", "0.1", "--out", str(tmp_path / "bench"))
    saved = tmp_path / "result.json"
    assert run_cli(*common, "--results", str(saved)).returncode == 0
    import oodmon

    monkeypatch.syspath_prepend(str(Path(oodmon.__file__).parent.parent / "scripts"))  # it imports sweep_full_depth
    script = load_script("episode_noise")[1]
    with pytest.raises(SystemExit, match="at least twice"):
        script.measure(saved, "ensemble", "cartpole:length=2.0", tmp_path / "models", 5, 4)
    row = script.measure(saved, "ensemble", "cartpole:length=2.0", tmp_path / "models", 6, 4)
    bench = json.loads(saved.read_text())["rows"][0]["aurocs"]["0"]
    trial = row["trials"]["0"]
    assert trial["bench"] == round(bench, 4) and row["bench_episodes"] == [3, 2]
    assert 0.5 < trial["all"] <= 1.0 and 0.0 <= trial["noise"] < 0.5  # the ensemble sees length=2.0
    assert row["paper"] == [0.862, 0.826, 0.993, 0.864, 0.87]
    # A file whose figure is not what these episodes give (other models, other seeds) is refused.
    data = json.loads(saved.read_text())
    data["rows"][0]["aurocs"]["0"] = bench - 0.01
    (tmp_path / "other.json").write_text(json.dumps(data))
    with pytest.raises(SystemExit, match="not the bench's models or episodes"):
        script.measure(tmp_path / "other.json", "ensemble", "cartpole:length=2.0", tmp_path / "models", 6, 4)


def test_bench_samples_sets_the_mc_agents_samples_per_decision_and_keys_its_cache(tmp_path):
    """--samples K: the Dropout and DropConnect agents decide and spread with K samples (each log
    says so), cached apart from the recipe's K; the results record it; bad values are refused."""
    common = ("bench", "--task", "cartpole", "--methods", "dropout,ensemble", "--trials", "1", "--variants",
              "cartpole:length=2.0", "--episodes", "1", "--id-episodes", "2", "--workers", "1",
              "--calibration-episodes", "3", "--far", "0.5", "--confidence", "none", "--out", str(tmp_path))
    default = run_cli(*common, "--json")
    assert default.returncode == 0, default.stderr
    more = run_cli(*common, "--samples", "50", "--json")
    assert more.returncode == 0, more.stderr
    assert json.loads(more.stdout)["config"]["samples"] == 50 and json.loads(default.stdout)["config"]["samples"] is None
    folders = sorted(p.name for p in (tmp_path / "logs").iterdir())
    assert folders == ["cartpole-chosen_std-far0.5-n3-marginal", "cartpole-chosen_std-far0.5-n3-marginal-k50"]
    for folder, dropout_k in zip(folders, ("20", "50")):
        logs = {m: read_log(tmp_path / "logs" / folder / m / "trial0" / "cartpole.mcap") for m in ("dropout", "ensemble")}
        assert logs["dropout"].metadata["about.samples"] == dropout_k
        assert logs["ensemble"].metadata["about.samples"] == "5"  # an ensemble's members, whatever K
    for bad in ("1", "x"):
        refused = run_cli(*common, "--samples", bad)
        assert refused.returncode == 2 and "--samples" in refused.stderr


def test_bench_members_trains_ensembles_of_that_size_keeping_members_trained_before(tmp_path):
    """--members K: every ensemble trial (trial 0 too: the zoo's has the recipe's 5) is trained with
    K members into folders of its own, its logs say K; member k trains alone with the same seed at
    any size, so the members of a smaller ensemble's training are kept, not trained again."""
    common = dict(methods=("ensemble",), trials=1, variants=("cartpole:length=2.0",), episodes=1, id_episodes=2,
                  eval_episodes=1, calibration_episodes=3, far=0.5, confidence=None, out=str(tmp_path), workers=1,
                  train_steps=300)
    two = BenchConfig("cartpole", members=2, **common)
    assert (two.model_name("ensemble"), two.recipe("ensemble").n_members) == ("ensemble-members2", 2)
    run_bench(two)
    small = tmp_path / "models/cartpole-ensemble-members2-trial0"
    assert json.loads((small / "model.json").read_text())["architecture"]["n_members"] == 2
    log = read_log(tmp_path / "logs" / f"cartpole-{two.cache_key()}" / "ensemble-members2/trial0/cartpole.mcap")
    assert log.metadata["about.samples"] == "2"
    # A 3-member training of the same trial begins where the 2-member one's members are.
    large = tmp_path / "models/cartpole-ensemble-members3-trial0"
    shutil.copytree(small / "runs", large / "runs")
    kept = {p: p.stat().st_mtime_ns for p in (large / "runs").rglob("*") if p.is_file()}
    three = BenchConfig("cartpole", members=3, **common)
    run_bench(three)
    assert {p: p.stat().st_mtime_ns for p in kept} == kept  # members 0 and 1: nothing trained again
    assert json.loads((large / "runs/member2/state.json").read_text())["finished"]
    before, after = load_file(str(small / "model.safetensors")), load_file(str(large / "model.safetensors"))
    shared = [name for name in before if name in after]
    assert shared and all(np.array_equal(before[n].numpy(), after[n].numpy()) for n in shared)
    assert len(after) > len(before)  # member 2's tensors too
    # The recipe's size is the shipped ensemble: trial 0 is the zoo's agent again.
    assert BenchConfig("cartpole", members=5, **common).model_name("ensemble") == "ensemble"


def test_bench_net_arch_trains_every_trial_with_those_widths_in_folders_of_its_own(tmp_path, capsys):
    """--net-arch 16,16: every trial (trial 0 too: the zoo's agent has the recipe's widths) trains
    with those hidden widths into folders of their own; the recipe's widths are the zoo's agent
    again; the results' settings record them (a baseline of other widths is refused by them)."""
    common = dict(methods=("dropconnect",), trials=1, variants=("cartpole:length=2.0",), episodes=1, id_episodes=2,
                  eval_episodes=1, calibration_episodes=3, far=0.5, confidence=None, workers=1, train_steps=300)
    small = BenchConfig("cartpole", net_arch=[16, 16], out=str(tmp_path), **common)  # a list, as JSON gives it
    assert small.net_arch == (16, 16) and small.model_name("dropconnect") == "dropconnect-net16x16"
    assert small.recipe("dropconnect").net_arch == [16, 16] and small.recipe("dropconnect").drop_p == 0.02
    run_bench(small)  # 300 steps: the trial fails in ID already, so no variant gives a row
    model = tmp_path / "models/cartpole-dropconnect-net16x16-trial0"
    assert json.loads((model / "model.json").read_text())["architecture"]["net_arch"] == [16, 16]
    assert (tmp_path / "logs" / f"cartpole-{small.cache_key()}" / "dropconnect-net16x16/trial0/cartpole.mcap").exists()
    assert small.what_made_the_numbers()["net_arch"] == [16, 16]
    assert BenchConfig("cartpole", net_arch=(256, 256), out=str(tmp_path), **common).model_name("dropconnect") == "dropconnect"
    from oodmon.cli import main

    assert main(["bench", "--task", "cartpole", "--methods", "dropconnect", "--net-arch", "16,x"]) == 2
    assert "'16,x' is not a list of hidden widths such as 64,64" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="Pong's CNN agents"):
        BenchConfig("pong", methods=("dropout",), net_arch=(64,))


@pytest.mark.parametrize("change, message", [({"members": 1}, "2 or more"),
                                             ({"methods": ("dropout",), "members": 10}, "ensemble method")])
def test_bench_members_refuses_what_it_cannot_size(change, message):
    with pytest.raises(ConfigError, match=message):
        BenchConfig("cartpole", **({"methods": ("ensemble",)} | change))


def test_a_baseline_checks_the_alarms_lead_relatively_and_skips_it_where_the_baseline_has_none():
    from oodmon.bench.baseline import bench_falls

    def result(lead):
        alarm = {"method": "sb3", "variant": "Hopper-v5:obs.stuck[3]=1.0", "false_alarm_rate": None,
                 "before_failure_rate": 1.0, "delay_median": 4.0}
        return {"config": {"task": "Hopper-v5"}, "rows": [],
                "alarms": [alarm | ({} if lead is None else {"lead_median": lead})]}

    assert bench_falls(result(49.5), result(50.0)) == []  # 1% shorter: within the tolerance, 2% of 50 steps
    assert bench_falls(result(45.0), result(50.0)) == [
        "alarms/sb3/Hopper-v5:obs.stuck[3]=1.0: lead_median fell from 50 to 45 (tolerance 0.02)"]
    assert bench_falls(result(80.0), result(50.0)) == []  # an earlier warning is no fall
    assert bench_falls(result(45.0), result(None)) == []  # results from before the lead was recorded


def test_a_baseline_of_other_fits_or_weights_is_said_to_be_so():
    """The notes beside figures that fell: the (method, trial)s whose weights, or whose fitted
    detectors (by detector), differ from the baseline's; nothing where both are the same."""
    from oodmon.bench.baseline import provenance_notes

    ours = {"weights": {"dropout": {0: "a" * 64, 1: "b" * 64}},
            "fitted": {"dropout": {0: {"dynamics": "sha256:1", "combined": "sha256:2"}, 1: {}}}}
    same = json.loads(json.dumps(ours))  # as read from a file: trials as text
    assert provenance_notes(ours, same) == []
    refitted = json.loads(json.dumps(ours))
    refitted["fitted"]["dropout"]["0"]["combined"] = "sha256:3"  # fitted on another CPU kind, say
    [note] = provenance_notes(ours, refitted, "base.json")
    assert note.startswith("base.json's numbers are of detectors fitted otherwise: dropout trial 0 (combined);")
    retrained = json.loads(json.dumps(ours))
    retrained["weights"]["dropout"]["1"] = "c" * 64
    [note] = provenance_notes(ours, retrained)
    assert f"other weights: dropout trial 1 ({'c' * 12} there, {'b' * 12} here)" in note
    fewer = {"weights": {"dropout": {"0": "a" * 64}}, "fitted": {"dropout": {"0": ours["fitted"]["dropout"][0]}}}
    assert provenance_notes(ours, fewer) == []  # a trial the baseline lacks is no difference of provenance
    assert "records neither" in provenance_notes(ours, {"rows": []})[0]
    elsewhere = dict(same, machine="x86_64; AMD EPYC; torch AVX2")
    assert provenance_notes(dict(ours, machine="x86_64; Intel Xeon; torch AVX512"), elsewhere, "b.json") == [
        "b.json was made on x86_64; AMD EPYC; torch AVX2; this run on x86_64; Intel Xeon; torch AVX512"]
    assert provenance_notes(dict(ours, machine="m"), dict(same, machine="m")) == []
    # a record of before the CPU's family and model were written cannot tell a CPU from another of its name
    here = "x86_64; AMD EPYC (family 25, model 17); OpenBLAS SkylakeX; torch AVX512"
    [note] = provenance_notes(dict(ours, machine=here), dict(same, machine="x86_64; AMD EPYC; torch AVX512"), "b.json")
    assert note.endswith(f"this run on {here} (the baseline's record names no CPU family and model, as before "
                         "2026-12-03: the same CPU or another)")


def test_a_cell_whose_log_cannot_be_written_names_the_log_and_leaves_no_part(tmp_path, monkeypatch):
    """A full disk under a bench's cells was 'oodmon: error: [Errno 28] No space left on device',
    naming no file, with the cells' .part logs left (measured on a 600 KB tmpfs)."""
    from oodmon.agents import zoo_dir
    from oodmon.bench.cells import _run_cell
    from oodmon.monitor import Threshold
    from oodmon.monitor.sinks.mcap import McapSink

    def full_disk(self, part):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(McapSink, "_open_part", full_disk)
    Threshold(6.0, "chosen_std", 1, "episode", 0.05, 20, 100, task="cartpole", method="ensemble").save(tmp_path / "t.json")
    log = tmp_path / "logs" / "cartpole.mcap"
    with pytest.raises(OSError, match=rf"^{re.escape(str(log))} could not be written \(No space left on device; "):
        _run_cell("cartpole", str(zoo_dir() / "cartpole-ensemble"), str(tmp_path / "t.json"), "cartpole", 1, 0, str(log))
    assert list((tmp_path / "logs").iterdir()) == []


def _half_second_job(folder: Path, job: int) -> int:
    import time

    time.sleep(0.5)
    (folder / str(job)).touch()
    return job


def _job_saying_its_start_and_end(folder: Path, job: int, seconds: float) -> int:
    """Writes ``<job>.<its worker's pid>`` as it starts and ``<job>.end`` ``seconds`` later."""
    import time

    (folder / f"{job}.{os.getpid()}").touch()
    time.sleep(seconds)
    (folder / f"{job}.end").touch()
    return job


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="forked workers: Linux's")
def test_the_bench_pools_workers_are_forked_from_the_bench_where_the_default_is_python_3_14s_forkserver(monkeypatch):
    """Python 3.14 made Linux's default start method "forkserver". The bench's pool took the
    default: each of its workers, a child of the server rather than of the bench, ended itself as
    it started (it dies with the bench, and checks that its parent is the bench), and
    ``oodmon bench --workers 2`` stopped at once: "A process in the process pool was terminated
    abruptly" (on 3.11 with that default set, 2026-12-01). On Linux its workers are forked
    from the bench, whatever the default."""
    import multiprocessing.context

    from oodmon.bench.cells import stopping_pool

    monkeypatch.setattr(multiprocessing.context._default_context, "_actual_context",
                        multiprocessing.get_context("forkserver"))
    assert multiprocessing.get_start_method() == "forkserver"
    with stopping_pool(2) as pool:
        assert pool.submit(os.getppid).result() == os.getpid()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="its workers' states: Linux's /proc")
def test_the_bench_pool_stops_its_queued_jobs_on_an_interrupt(tmp_path):
    """An interrupt while the bench's workers play (its trainings, preparations, cells) cancels the
    jobs not begun and kills the workers at once; `with ProcessPoolExecutor` waited for every
    queued job (Ctrl-C at a CartPole bench's first cell ran 100 of its 102 cells). Two workers, job
    0 at once and 19 jobs of 5 s: waiting for the queue would take 50 s, for the jobs begun 5 s.
    Nothing here hangs on the machine's speed (this test counted half-second jobs finished before
    the stop until 2026-12-06, and failed once on a loaded machine): up to the stop, which comes
    when job 0 is done, the workers can have begun jobs 1 and 2 only, and finished none of them."""
    import time

    from oodmon.bench.cells import stopping_pool

    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt), stopping_pool(2) as pool:
        jobs = [pool.submit(_job_saying_its_start_and_end, tmp_path, job, 0.0 if job == 0 else 5.0)
                for job in range(20)]
        jobs[0].result()
        raise KeyboardInterrupt  # Ctrl-C here
    stopped = time.monotonic() - started
    names = sorted(path.name for path in tmp_path.iterdir())
    begun = {int(name.split(".")[0]): int(name.split(".")[1]) for name in names if not name.endswith(".end")}
    assert [name for name in names if name.endswith(".end")] == ["0.end"], names  # no 5 s job ran out
    assert 0 in begun and set(begun) <= {0, 1, 2} and stopped < 5, (names, stopped)
    assert [pid for pid in set(begun.values()) if not wait_until_dead(pid, 3.0)] == []  # killed: none to go on
    assert sorted(path.name for path in tmp_path.iterdir()) == names
    with stopping_pool(2) as pool:  # and without one, every job's result
        assert sorted(pool.map(_half_second_job, [tmp_path] * 4, range(20, 24))) == [20, 21, 22, 23]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="its workers' states: Linux's /proc")
def test_the_bench_pool_kills_the_workers_still_starting_when_the_interrupt_comes(tmp_path, monkeypatch):
    """Ctrl-C as the first jobs are queued, before the workers have begun (a bench's first moments;
    here each worker takes half a second to start, as on a loaded machine): the pool killed the
    workers that had said their pid as they started, none yet, and the rest took the queued jobs
    and ran them out, and the bench at its exit waited for them (its trainings: hours). It now
    kills every worker it forked."""
    import time

    import oodmon.side_by_side
    from oodmon.bench.cells import stopping_pool

    def slow_start(parent: int, die_with=oodmon.side_by_side.die_with) -> None:
        time.sleep(0.5)
        die_with(parent)

    monkeypatch.setattr(oodmon.side_by_side, "die_with", slow_start)  # (the workers fork with it)
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt), stopping_pool(2) as pool:
        for job in range(20):
            pool.submit(_job_saying_its_start_and_end, tmp_path, job, 5.0)
        raise KeyboardInterrupt  # Ctrl-C here
    assert time.monotonic() - started < 4  # (the jobs begun would take 5 s)
    time.sleep(1.5)  # a worker not killed has started by now, and begun a job
    begun = {int(path.name.split(".")[1]) for path in tmp_path.iterdir() if not path.name.endswith(".end")}
    still = [pid for pid in begun if not wait_until_dead(pid, 3.0)]
    assert still == [], sorted(path.name for path in tmp_path.iterdir())


@pytest.mark.parametrize("given, said", [
    ({}, ["the monitor's protocol", "the steps its shifts", "shifts of your own"]),
    ({"protocol": "monitor", "onsets": (20, 100)}, ["shifts of your own (--variants MountainCar-v0:NAME=VALUE"]),
    ({"protocol": "monitor", "onsets": (20, 100), "variants": ("MountainCar-v0:gravity=0.005",), "obs_noise": 0.01},
     ["no --obs-noise"]),
])
def test_a_bench_of_your_own_env_names_each_thing_it_lacks_and_only_those(given, said):
    config = {"task": "MountainCar-v0", "sb3": ("model.zip",), "env_id": "MountainCar-v0", "methods": ("sb3",)} | given
    with pytest.raises(ConfigError, match="MountainCar-v0 is an env oodmon has no variants of: bench it with ") as raised:
        BenchConfig(**config)
    parts = str(raised.value).split("bench it with ", 1)[1].split("; ")
    assert [part for part in parts if not part.startswith(tuple(said))] == [] and len(parts) == len(said)


def test_an_interrupted_bench_says_how_far_it_got(tmp_path, monkeypatch, capsys):
    """Ctrl-C said "trained models and finished cells are kept" of a bench stopped before either
    (2026-12-06): it now says what its stages had reached."""
    import oodmon.bench
    import oodmon.bench.run
    from oodmon.cli import main
    from oodmon.cli.bench import PREPARING

    def stopped_at(*reports):
        def run(config, *, on_progress):
            for report in reports:
                on_progress(*report)
            raise KeyboardInterrupt
        return run

    command = ["bench", "--task", "cartpole", "--methods", "dropout", "--trials", "2", "--out", str(tmp_path)]
    for reports, said in [
        ([], "trained models and finished cells are kept: the same command resumes from them"),
        ([("trained trial models", 0, 1)], "no trial model was trained yet (a training under way goes on from its "
                                           "last checkpoint, if it wrote one): the same command goes on from them"),
        ([("trained trial models", 1, 1), ("monitored cells", 3, 12)],
         "the trial models, their thresholds and 3 of the 12 monitored cells are kept: the same command goes on from "
         "them"),
        ([(PREPARING, 1, 2)], "the trial models and 1 of the 2 trials' fitted detectors, thresholds and failing "
                              "variants are kept: the same command goes on from them")]:
        monkeypatch.setattr(oodmon.bench, "run_bench", stopped_at(*reports))
        assert main(command) == 130
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"oodmon: interrupted; {said}"
    # the stage's name as the bench reports it (a bench that trains nothing, stopped as it fits: 2026-12-06)
    reported = []
    monkeypatch.setattr(oodmon.bench.run, "_prepare_trial", lambda config, method, trial, report, workers: "parts")
    config = BenchConfig(task="cartpole", methods=("dropout",), trials=1)
    oodmon.bench.run._prepare_trials(config, [("dropout", 0)], 1, lambda *report: reported.append(report))
    assert reported == [(PREPARING, 0, 1), (PREPARING, 1, 1)]
