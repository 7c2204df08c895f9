"""The package's public surface: four parts under one import name, each with a complete __all__."""

from __future__ import annotations

import ast
import importlib
import inspect
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import pytest

import oodmon
from tests.helpers import blas_threads, load_script

PARTS = ["oodmon.envs", "oodmon.agents", "oodmon.monitor", "oodmon.replay"]
ROOT = Path(oodmon.__file__).parent.parent
TOOLS = sorted(p for p in [*(ROOT / "scripts").glob("*.py"), *(ROOT / "benchmarks").glob("*.py")]
               if 'if __name__ == "__main__":' in p.read_text())  # (not the modules they import: timing.py, masked_cartpole.py)


@pytest.mark.parametrize("name", PARTS + ["oodmon", "oodmon.errors"])
def test_all_is_complete_and_importable(name):
    module = importlib.import_module(name)
    public = {
        attr for attr, value in vars(module).items()
        if not attr.startswith("_") and not inspect.ismodule(value)
        and getattr(value, "__module__", name).startswith("oodmon")
        and attr not in {"annotations"}
    }
    assert public <= set(module.__all__), f"missing from {name}.__all__: {public - set(module.__all__)}"
    for attr in module.__all__:
        assert hasattr(module, attr)


def test_import_oodmon_registers_the_envs_in_a_fresh_interpreter():
    code = (
        "import oodmon, gymnasium; "
        "env = gymnasium.make('oodmon/CartPole-v1', length=2.0); "
        "print(env.unwrapped.length, env.spec.max_episode_steps)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["2.0", "500"]


def test_registered_ids():
    for env_id in ("oodmon/CartPole-v1", "oodmon/Pendulum-v1", "oodmon/Pong-v5"):
        assert env_id in gymnasium.registry
    assert gymnasium.registry["oodmon/Pendulum-v1"].max_episode_steps == 200
    ids = ("oodmon/CartPole-v1", "oodmon/Pendulum-v1", "oodmon/Pong-v5")
    specs = [gymnasium.registry[env_id] for env_id in ids]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # gymnasium warns when an id is registered over
        oodmon.envs.register_envs()  # registering twice is harmless: the same specs, no warning
    assert [gymnasium.registry[env_id] for env_id in ids] == specs
    assert gymnasium.make("oodmon/CartPole-v1", length=2.0).unwrapped.length == 2.0


def test_import_oodmon_does_not_load_the_heavy_parts():
    code = "import sys, oodmon; print(sorted(m for m in ('torch', 'rerun', 'ale_py', 'stable_baselines3', 'cv2') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_replay_does_not_load_torch():
    # Replay reads logs on machines that never ran a policy: it should not pay for torch or SB3.
    code = ("import sys, oodmon.replay, oodmon.cli; "
            "print(sorted(m for m in ('torch', 'stable_baselines3', 'rerun', 'cv2') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_readmes_layout_names_every_part_of_the_package():
    from pathlib import Path

    root = Path(oodmon.__file__).parent
    readme = (root.parent / "README.md").read_text()
    block = readme[readme.index("## Layout"):]
    block = block[block.index("```\noodmon/\n"):block.index("\ntests/")]
    listed = set()
    for line in block.splitlines()[2:]:
        if line.startswith("  ") and not line.startswith("   "):
            listed.update(name.strip(",") for name in line.split()[:2] if name.endswith(("/", ".py", ".py,", ".json")))
    present = {p.name + ("/" if p.is_dir() else "") for p in root.iterdir()
               if not p.name.startswith("__") and p.suffix in ("", ".py", ".json") and p.name != "py.typed"}
    assert listed == present


def test_an_installed_package_holds_every_file_oodmon_reads_beside_its_code():
    """``pip install`` of a wheel copies only the modules and the files pyproject.toml's
    package-data names; the editable install of ``make`` reads them all from the clone, so a data
    file left out of those patterns (a new kind of detector file, say) breaks only the installed
    package: its zoo agents, the paper's tables or the Foxglove layout missing. (Checked by hand
    on 2026-12-04: a wheel of the package, installed in a fresh virtual environment outside the
    clone, ran `oodmon demo` and replayed its logs.)"""
    import tomllib

    package = Path(oodmon.__file__).parent
    patterns = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["oodmon"]
    # the patterns as setuptools reads them: globs under the package's folder
    shipped = {pattern: {p for p in package.glob(pattern) if p.is_file()} for pattern in patterns}
    assert all(shipped.values()), [pattern for pattern, files in shipped.items() if not files]  # none stale
    try:
        listed = subprocess.run(["git", "ls-files", "-z", "oodmon"], cwd=ROOT, capture_output=True, check=True).stdout
        files = {ROOT / name for name in listed.decode().split("\0") if name}
    except (OSError, subprocess.CalledProcessError):  # not a clone: the files in the folder
        files = {p for p in package.rglob("*") if p.is_file() and "__pycache__" not in p.parts}
    data = {p for p in files if p.suffix not in (".py", ".pyc")}
    # the zoo's 9 agents (a model and a detector set each, two files apiece), its README, the paper's
    # tables and the Foxglove layout
    assert len(data) >= 39
    left_out = data - set().union(*shipped.values())
    assert not left_out, sorted(str(p.relative_to(package)) for p in left_out)


def test_every_progress_callback_of_the_library_has_the_one_shape():
    """Long work reports through ``on_progress(stage, done, total)`` (oodmon.progress), nowhere else."""
    import re
    from pathlib import Path

    root = Path(oodmon.__file__).parent
    for path in root.rglob("*.py"):
        found = re.findall(r"\bon_episode\b|\bon_step=|\bReporter\b", path.read_text())
        assert not found, f"{path.relative_to(root)} still has {found}"


def test_the_docs_five_trial_tables_are_what_the_committed_results_give():
    """Tables made from results/bench/*.json by scripts/bench_table.py, never typed by hand: each
    file's table once, in docs/bench.md (the shipped agents' main files) or in results/bench/README.md."""
    root, script = load_script("bench_table")
    readmes = [(root / name).read_text() for name in ("docs/bench.md", "results/bench/README.md")]
    results = sorted((root / "results" / "bench").glob("*.json"))
    assert results, "results/bench/ holds the committed five-trial results"
    for path in results:
        begin = f"<!-- bench_table {path.stem} -->\n"
        assert sum(text.count(begin) for text in readmes) == 1, f"not one table of {path.name} in the READMEs"
        readme = next(text for text in readmes if begin in text)
        shown = readme[readme.index(begin) + len(begin):readme.index("\n<!-- end bench_table -->", readme.index(begin))]
        assert shown == script.table(path), f"the table of {path.name} is not the script's"
        data = json.loads(path.read_text())
        assert {m: len(t) for m, t in data["id_returns"].items()} == {
            m: data["config"]["trials"] for m in data["config"]["methods"]}, f"{path.name} lacks trials' ID returns"


def test_the_docs_goals_at_a_glance_are_what_the_committed_results_give():
    root, script = load_script("bench_table")
    readme = (root / "docs" / "bench.md").read_text()
    begin, end = "<!-- bench_goals -->\n", "\n<!-- end bench_goals -->"
    shown = readme[readme.index(begin) + len(begin):readme.index(end)]
    assert shown == script.goals(sorted((root / "results" / "bench").glob("*.json")))


def test_the_goals_take_per_variant_the_row_meeting_both_then_the_mean_then_the_highest(tmp_path):
    script = load_script("bench_table")[1]
    # The paper's CartPole ensemble: gravity=98.0 0.772 ± 0.040, length=2.0 0.883 ± 0.057.
    def result(name, rows, **config):
        data = {"config": {"task": "cartpole", "methods": ["ensemble"], "trials": 5, **config},
                "rows": [{"method": "ensemble", "variant": v, "detector": d, "mean": m, "std": sd,
                          "aurocs": dict.fromkeys("01234", m)} for v, d, m, sd in rows]}
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(data))
        return path

    files = [
        result("a", [("cartpole:gravity=98.0", "spread", 0.95, 0.10),  # the higher mean, its std too large
                     ("cartpole:length=2.0", "spread", 0.80, 0.01)]),   # below the paper's mean
        result("b", [("cartpole:gravity=98.0", "scaled_spread", 0.90, 0.02),  # both met: taken
                     ("cartpole:length=2.0", "spread", 0.60, 0.01)], detectors=["spread", "scaled_spread"]),
        result("c", [("cartpole:gravity=98.0", "spread", 0.99, 0.0)], members=20),  # an ensemble the zoo does not ship
    ]
    lines = script.goals(files).splitlines()
    gravity = next(line for line in lines if "gravity=98.0" in line)
    length = next(line for line in lines if "length=2.0" in line)
    assert "0.900 ± 0.020 (5) | `b`, `scaled_spread` | yes | yes |" in gravity
    assert "0.800 ± 0.010 (5) | `a`, `spread` | no | no |" in length
    assert lines[-1] == ("Best mean AUROC, cartpole: ours 0.900 (ensemble gravity=98.0, `b`, `scaled_spread`), the paper's "
                         "0.883 (ensemble length=2.0).")
    # One failing trial's row has no std to hold against the paper's: neither met nor missed, and a
    # row over five trials meeting both is taken before its higher mean
    one = tmp_path / "e.json"
    data = json.loads(result("e", [("cartpole:gravity=98.0", "spread", 0.97, 0.0)]).read_text())
    data["rows"][0] |= {"aurocs": {"3": 0.97}, "aupr_mean": 0.9, "fpr95_mean": 0.1}
    data |= {"command": "oodmon bench", "monitor": {}}
    data["config"]["score"] = "margin_std"
    one.write_text(json.dumps(data))
    alone = next(line for line in script.goals([one]).splitlines() if "gravity=98.0" in line)
    assert alone.endswith("0.970 ± 0.000 (1) | `e`, `spread` | yes | one trial: no std |")
    assert "`b`, `scaled_spread` | yes | yes |" in next(line for line in script.goals([one, files[1]]).splitlines()
                                                        if "gravity=98.0" in line)
    assert "| yes | one trial: no std |" in script.table(one) and "ensemble 1/2 (0/2)" in script.table(one)
    only_dropout = script.goals([result("d", [], methods=["dropout"])]).splitlines()
    assert all("does not fail (in any file)" in line for line in only_dropout[2:5])
    assert only_dropout[-1] == ("Best mean AUROC, cartpole: ours none (no variant failed), the paper's 0.712 "
                                "(dropout force_mag=2.5).")


def test_a_file_scoring_every_trial_says_how_many_of_them_fail_and_its_std_is_judged(tmp_path, monkeypatch):
    """``oodmon bench --all-variants`` scores every trial on every variant it names, failing or not (the
    paper scored its five trials on the variants its trained model failed on): the tables and the
    goals say per row how many trials it averages and how many of them fail, and judge its std over
    them; the plot says it under each variant."""
    root, script = load_script("bench_table")
    import oodmon.outputs

    aurocs = {"0": 0.99, "1": 0.93, "2": 0.95, "3": 0.96, "4": 0.97}
    rows = [{"method": "ensemble", "variant": variant, "detector": "spread", "aurocs": aurocs, "mean": 0.96,
             "std": 0.02, "aupr_mean": 0.9, "fpr95_mean": 0.1}  # (the std of those five)
            for variant in ("cartpole:gravity=98.0", "cartpole:length=2.0")]
    data = {"command": "oodmon bench --all-variants", "monitor": {}, "rows": rows,
            "config": {"task": "cartpole", "methods": ["ensemble"], "trials": 5, "score": "margin_std",
                       "all_variants": True},
            "failing": {"ensemble": {"0": ["cartpole:length=2.0"], **{t: [] for t in "1234"}}},
            "id_returns": {"ensemble": dict.fromkeys("01234", 500.0)}}
    path = tmp_path / "every.json"
    path.write_text(json.dumps(data))
    lines = script.goals([path]).splitlines()
    assert next(line for line in lines if "length=2.0" in line).endswith(
        "| 0.960 ± 0.020 (5 scored, 1 fails) | `every`, `spread` | yes | yes |")  # the paper's 0.883 ± 0.057
    assert "| 0.960 ± 0.020 (5 scored, none fail) |" in next(line for line in lines if "gravity=98.0" in line)
    assert "| ensemble | length=2.0 | 0.960 ± 0.020 (5 scored, 1 fails) |" in script.table(path)
    drawn = []
    monkeypatch.setattr(oodmon.outputs, "save_figure", lambda fig, path: drawn.append(fig) or path)
    script.plot(path)
    axes = drawn[0].axes[0]
    assert sorted(text.get_text() for text in axes.texts) == ["of 5: 1 fails", "of 5: none fail"]
    assert "ours (all 5 trials)" in [text.get_text() for text in axes.get_legend().get_texts()]


def test_the_plot_of_a_result_says_how_many_trials_a_point_of_fewer_than_all_averages(monkeypatch):
    """A point over the trials that failed on the variant, where fewer than all did, says their number
    (the committed Pendulum file: Dropout m=5.0 over 3 trials, the ensemble's m=0.05 over 1, whose
    std of 0 is one trial's); a point over all five says nothing."""
    root, script = load_script("bench_table")
    import oodmon.outputs

    drawn = []
    monkeypatch.setattr(oodmon.outputs, "save_figure", lambda fig, path: drawn.append(fig) or path)
    script.plot(root / "results" / "bench" / "pendulum-pre_squash_std.json")
    said = {ax.get_title(): sorted(text.get_text() for text in ax.texts if text.get_text().startswith("n="))
            for ax in drawn[0].axes}
    assert said == {"pendulum dropout": ["n=3"], "pendulum dropconnect": ["n=4"], "pendulum ensemble": ["n=1"]}


def test_goals_of_given_files_are_over_those_files_alone(capsys):
    """``bench_table.py --goals FILE...``: the goals at a glance over those files (another draw of
    trials, say), not the committed ones; a file that is not there, or --plots beside it, refused
    (``sys.exit`` with the message: exit code 1, the message on stderr). Run in this process: a
    subprocess of the script costs seconds of imports."""
    root, script = load_script("bench_table")
    draw = root / "results" / "sweeps" / "pendulum-dropout-fixed-masks-avx512-bench.json"
    script.main(["--goals", str(draw)])
    shown = capsys.readouterr().out
    assert shown == script.goals([draw]) + "\n"
    rows = [line for line in shown.splitlines() if line.startswith("| pendulum | dropout |")]
    assert len(rows) == 3 and all("pendulum-dropout-fixed-masks-avx512-bench" in r or "does not fail" in r for r in rows)
    assert not any(line.startswith("| cartpole") for line in shown.splitlines())  # no committed file read
    for extra, said in (([str(root / "nope.json")], "no such results file"), ([str(draw), "--plots"], "--goals draws nothing")):
        with pytest.raises(SystemExit) as refused:
            script.main(["--goals", *extra])
        assert isinstance(refused.value.code, str) and said in refused.value.code and not capsys.readouterr().out


def test_the_five_trial_tables_name_the_trials_that_do_not_solve_the_task():
    script = load_script("bench_table")[1]
    line = script._id_return_line({"dropout": {"0": 500.0, "1": 500.0, "2": 500.0},
                                   "dropconnect": {"0": 500.0, "1": 297.45, "2": 147.0}}, "cartpole")
    assert line == ("ID return of trials 0-2 (their training's 20 episodes; the task counts as solved at >= 475): "
                    "dropout 500, 500, 500; dropconnect 500, 297.45, 147 (trials 1, 2 below it).")
    assert "(trial 1 below it)" in script._id_return_line({"ensemble": {"0": -164.8, "1": -210.0}}, "pendulum")


@pytest.mark.parametrize("name, readme", [("sweep_full_depth", "oodmon/zoo/README.md"),
                                          ("sweep_trials", "oodmon/zoo/README.md"),
                                          ("sweep_samples", "oodmon/zoo/README.md"),
                                          ("sweep_inference_p", "oodmon/zoo/README.md"),
                                          ("episode_noise", "results/bench/README.md"),
                                          ("combined_long_mean", "docs/detectors.md")])
def test_readme_sweep_tables_are_made_from_the_committed_rows(name, readme, monkeypatch):
    """The READMEs' sweep tables are the scripts' --table output on results/sweeps/, verbatim."""
    root = Path(oodmon.__file__).parent.parent
    monkeypatch.chdir(root)  # the scripts read results/sweeps/ from the working directory
    monkeypatch.syspath_prepend(str(root / "scripts"))  # they import sweep_full_depth beside them
    table = load_script(name)[1].table()
    assert table.count("\n") >= 3, f"{name} has no rows in results/sweeps/"
    assert table in (root / readme).read_text(), f"{readme}'s table of {name} is not the script's"


def test_readme_detector_table_is_made_from_the_committed_results():
    """docs/detectors.md's detector table is scripts/detector_table.py's output on results/detectors/."""
    root, script = load_script("detector_table")
    readme = (root / "docs" / "detectors.md").read_text()
    begin, end = "<!-- detector_table -->\n", "\n<!-- end detector_table -->"
    assert begin in readme and end in readme, "docs/detectors.md lacks the detector table's markers"
    assert readme[readme.index(begin) + len(begin):readme.index(end)] == script.table()


def test_readme_pong_spread_score_table_is_made_from_the_committed_results(monkeypatch, capsys):
    """docs/pong.md's table of spread scores is scripts/pong_spread_scores.py's on its results file,
    as its ``--table`` prints it (from the repository's root, as its Run: line has it)."""
    monkeypatch.syspath_prepend(str(ROOT / "scripts"))
    root, script = load_script("pong_spread_scores")
    results = json.loads((root / "results" / "detectors" / "spread-scores-pong.json").read_text())
    assert sorted(results) == ["dropconnect", "dropout", "ensemble"]
    assert script.table(results) in (root / "docs" / "pong.md").read_text()
    monkeypatch.chdir(root)
    script.main(["--table"])
    assert capsys.readouterr().out == script.table(results) + "\n"


def test_the_pong_scripts_measure_every_agent_unless_some_are_named(monkeypatch, capsys):
    """argparse's ``choices`` refused no method at all (Python 3.11: ``invalid choice: []``), the
    default of measure_pong_features.py and of pong_spread_scores.py, which now check each name."""
    import argparse

    monkeypatch.syspath_prepend(str(ROOT / "scripts"))
    script = load_script("measure_pong_features")[1]
    assert script.method_arguments(argparse.ArgumentParser(), []).methods == ["ensemble", "dropout", "dropconnect"]
    assert script.method_arguments(argparse.ArgumentParser(), ["dropout"]).methods == ["dropout"]
    with pytest.raises(SystemExit):
        script.method_arguments(argparse.ArgumentParser(), ["dropout", "ensembles"])
    assert "no shipped Pong agent 'ensembles'; choose from ensemble, dropout, dropconnect" in capsys.readouterr().err


def test_scripts_run_with_oodmon_torch_threads_keep_to_it(monkeypatch):
    """A script whose command reads ``OODMON_TORCH_THREADS=1 ...`` honours it as the CLI does (torch
    and numpy's BLAS otherwise take a thread per core: two such scripts on two cores each kept a
    second thread busy); ``limit_threads`` sets the value given to both, else one thread (or,
    asked, leaves them alone), and sets ``OPENBLAS_NUM_THREADS``, which a BLAS loaded later reads."""
    import numpy  # noqa: F401  (its BLAS loaded)
    import torch
    from threadpoolctl import threadpool_limits

    from oodmon.threads import limit_threads, set_threads

    scripts = Path(__file__).resolve().parents[1] / "scripts"
    documented = [p for p in sorted(scripts.glob("*.py")) if "OODMON_TORCH_THREADS" in p.read_text()]
    assert len(documented) >= 20
    deaf = [p.name for p in documented if "limit_threads()" not in p.read_text()]
    assert deaf == []
    before = torch.get_num_threads()
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "")  # restored after the test, which limit_threads sets
    try:
        torch.set_num_threads(2)
        original = threadpool_limits(2, user_api="blas")
        monkeypatch.delenv("OODMON_TORCH_THREADS", raising=False)
        assert limit_threads(default=None) is None and torch.get_num_threads() == 2 and blas_threads() == {2}
        assert limit_threads() == 1 and torch.get_num_threads() == 1 and blas_threads() == {1}
        assert os.environ["OPENBLAS_NUM_THREADS"] == "1"
        monkeypatch.setenv("OODMON_TORCH_THREADS", "2")
        assert limit_threads() == 2 and torch.get_num_threads() == 2 and blas_threads() == {2}
        assert os.environ["OPENBLAS_NUM_THREADS"] == "2"
        set_threads(1)  # a bench worker's: one, whatever the variable says
        assert torch.get_num_threads() == 1 and blas_threads() == {1} and os.environ["OPENBLAS_NUM_THREADS"] == "1"
        # a command that plays no policy (replay, check): the BLAS only, torch's threads as they were
        assert limit_threads(torch=False) == 2 and torch.get_num_threads() == 1 and blas_threads() == {2}
    finally:
        torch.set_num_threads(before)
        original.restore_original_limits()


@pytest.mark.parametrize("path", TOOLS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_script_and_benchmark_answers_help_with_its_docstring_and_does_no_work(path, monkeypatch, capsys):
    """`scripts/X.py --help` as a newcomer types it. Before 2026-12-01, nine scripts failed on it
    (they took "--help" for a method, a zoo name or a log: a traceback, or a usage line and exit
    code 1), and three scripts and eleven benchmarks ignored it and did their work (minutes of it)."""
    import runpy

    monkeypatch.syspath_prepend(str(path.parent))  # the tools' imports of their neighbours
    monkeypatch.setattr(sys, "argv", [str(path), "--help"])
    with pytest.raises(SystemExit) as ended:
        runpy.run_path(str(path), run_name="__main__")
    assert ended.value.code in (0, None)
    opening = " ".join(ast.get_docstring(ast.parse(path.read_text())).split()[:6])  # argparse rewraps it
    assert opening in " ".join(capsys.readouterr().out.split())
