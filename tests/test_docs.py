"""The README and the pages of docs/ link to each other by relative links; each must reach a file
that exists and, with an anchor, a heading of that file (anchors as GitHub makes them). The names
of oodmon they cite (`oodmon.envs.parse_variant`, a code block's imports) must exist, and so must
each option they give an `oodmon` command (`oodmon run --mcap`) or a script of scripts/ and
benchmarks/ (`scripts/bench_table.py --goals`), and each value they give an option of set choices:
a rename that leaves a page behind fails here."""

from __future__ import annotations

import argparse
import ast
import importlib
import re
from pathlib import Path

from oodmon.cli import _parser
from tests.helpers import DOC_PAGES

ROOT = Path(__file__).resolve().parents[1]
PAGES = DOC_PAGES


def anchors(path: Path) -> set[str]:
    """GitHub's anchor of each heading: lower case, punctuation but '-' and '_' dropped, spaces to '-'."""
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.DOTALL | re.MULTILINE)
    return {re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")
            for heading in re.findall(r"^#{1,6} (.+)$", text, flags=re.MULTILINE)}


def test_anchors_are_githubs():
    assert {"the-papers-benchmark", "trained-inside-vecnormalize", "five-trials-beside-the-papers"} <= (
        anchors(ROOT / "docs" / "bench.md") | anchors(ROOT / "docs" / "your-policy.md"))


def test_every_relative_link_reaches_a_file_and_its_heading():
    broken = []
    for page in PAGES:
        for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
            if re.match(r"[a-z]+://", target):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and anchor not in anchors(file):
                broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, broken


def test_every_page_is_listed_in_the_readme_and_in_the_docs_index():
    readme, index = (ROOT / "README.md").read_text(), (ROOT / "docs" / "README.md").read_text()
    for page in PAGES[1:]:
        if page.name != "README.md":
            assert f"](docs/{page.name})" in readme, page.name
            assert f"]({page.name})" in index, page.name


def _cited(name: str) -> bool:
    """Whether a dotted name (``oodmon.monitor.sb3_callback.MonitorCallback``) is a module or an attribute of one."""
    parts = name.split(".")
    for split in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:split]))
        except ImportError:
            continue
        for attribute in parts[split:]:
            if not hasattr(found, attribute):
                return False
            found = getattr(found, attribute)
        return True
    return False


READMES = [*PAGES, ROOT / "oodmon/zoo/README.md", ROOT / "benchmarks/README.md",
           *sorted(ROOT.glob("results/*/README.md"))]


def test_every_name_of_oodmon_the_pages_cite_exists():
    assert _cited("oodmon.envs.parse_variant") and not _cited("oodmon.envs.parse_varient")
    readmes = READMES
    missing, imports = [], 0
    for page in readmes:
        text = page.read_text()
        missing += [f"{page.relative_to(ROOT)}: {name}" for name in sorted(set(re.findall(r"`(oodmon(?:\.\w+)+)", text)))
                    if not _cited(name)]
        code = re.findall(r"```python\n(.*?)```", text, re.DOTALL) + re.findall(r'python -c "\n(.*?)\n"', text, re.DOTALL)
        for node in (node for block in code for node in ast.walk(ast.parse(block))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("oodmon"):
                imports += len(node.names)
                missing += [f"{page.relative_to(ROOT)}: from {node.module} import {alias.name}" for alias in node.names
                            if not _cited(f"{node.module}.{alias.name}")]
    assert imports >= 10 and not missing, missing  # 15 imports on 2026-12-04


def _commands_options() -> dict[str, dict[str, argparse.Action]]:
    """Each command of the CLI (``run``; ``envs show``) and its options, by option string."""
    def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
        return next((a.choices for a in parser._actions if isinstance(a, argparse._SubParsersAction)), {})

    commands = {}
    for name, parser in subcommands(_parser()).items():
        commands[name] = {option: action for action in parser._actions for option in action.option_strings}
        for inner, inner_parser in subcommands(parser).items():
            commands[f"{name} {inner}"] = {option: action for action in inner_parser._actions
                                           for option in action.option_strings}
    return commands


#: ``oodmon COMMAND`` and what follows it on its line (continuations joined), up to a code span's
#: end, a pipe, a ';' or a comment.
COMMAND_LINE = re.compile(r"\boodmon ((?:envs (?:show|tour))|[a-z][\w-]*)\b([^\n`|;#]*)")


def _options_given(rest: str) -> list[tuple[str, str]]:
    """The options on the rest of a command's line (``--mcap`` of ``--mcap=x`` too), each with the
    word after it (its value, if it takes one)."""
    words = [word.strip("[]()'\",") for word in rest.split()]
    return [(word.split("=")[0], following) for word, following in zip(words, [*words[1:], ""])
            if word.startswith("--")]


def wrong_options(text: str, commands: dict[str, dict[str, argparse.Action]]) -> tuple[int, list[str]]:
    """The options given to oodmon commands in ``text`` that the command has not, and the values
    given to an option of set choices that are none of them; with the number of options read."""
    wrong, read = [], 0
    for command, rest in COMMAND_LINE.findall(text.replace("\\\n", " ")):
        if command not in commands:  # prose: "oodmon reads ..."
            continue
        for option, following in _options_given(rest):
            read += 1
            action = commands[command].get(option)
            if action is None:
                wrong.append(f"oodmon {command} {option}")
            elif action.choices and re.fullmatch(r"[a-z][\w-]*", following) and following not in action.choices:
                wrong.append(f"oodmon {command} {option} {following}")
    return read, wrong


def test_every_option_the_pages_give_an_oodmon_command_exists():
    commands = _commands_options()
    assert wrong_options("`oodmon run --threshold t.json --mcpa x.mcap --method ensembel`, oodmon reads it\n"
                         "oodmon envs show cartpole:length=2.0 \\\n    --onset 30 --mcap x", commands) == (
        5, ["oodmon run --mcpa", "oodmon run --method ensembel", "oodmon envs show --mcap"])
    read, wrong = 0, []
    for page in READMES:
        page_read, page_wrong = wrong_options(page.read_text(), commands)
        read += page_read
        wrong += [f"{page.relative_to(ROOT)}: {what}" for what in page_wrong]
    assert read >= 900 and not wrong, wrong  # 1,010 options on 2026-12-05


def _script_options(path: Path, seen: frozenset[Path] = frozenset()) -> set[str]:
    """The option strings (``"--table"``) a script of scripts/ or benchmarks/ names, in its own code
    or in the modules beside it that it imports (a shared argument like the sweeps' ``--table``);
    of a shell script, every ``--word`` in it."""
    text = path.read_text()
    if path.suffix == ".sh":
        return set(re.findall(r"--[a-z][\w-]*", text))
    tree = ast.parse(text)
    options = {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant) and isinstance(node.value, str)
               and re.fullmatch(r"--[a-z][\w-]*", node.value)}
    imported = {alias.name for node in ast.walk(tree) if isinstance(node, ast.Import) for alias in node.names}
    imported |= {node.module for node in ast.walk(tree) if isinstance(node, ast.ImportFrom) and node.module}
    for name in imported:
        beside = path.parent / f"{name}.py"
        if beside.exists() and beside not in seen:
            options |= _script_options(beside, seen | {path})
    return options


#: A script of scripts/ or benchmarks/ and what follows it on its line, as COMMAND_LINE.
SCRIPT_LINE = re.compile(r"\b((?:scripts|benchmarks)/[\w/]+\.(?:py|sh))\b([^\n`|;#]*)")


def test_every_option_the_pages_give_a_script_exists():
    wrong, read = [], 0
    for page in READMES:
        for script, rest in SCRIPT_LINE.findall(page.read_text().replace("\\\n", " ")):
            path = ROOT / script
            if not path.exists():
                wrong.append(f"{page.relative_to(ROOT)}: {script} (no such file)")
                continue
            options = _script_options(path)
            for option, _ in _options_given(rest):
                read += 1
                if option not in options:
                    wrong.append(f"{page.relative_to(ROOT)}: {script} {option}")
    assert "--table" in _script_options(ROOT / "scripts" / "sweep_trials.py")  # given by a module it imports
    assert read >= 90 and not wrong, wrong  # 106 options on 2026-12-05
