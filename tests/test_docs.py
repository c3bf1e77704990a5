"""The commands the README quotes must still parse: scenario, policy and detector names, options and JSON
arguments are all checked by the CLI's parser (nothing is flown)."""
import re
import shlex
from pathlib import Path

import pytest

from ftcgym.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]


def quoted_commands(text: str) -> list[str]:
    """Every `ftcgym <subcommand> <arguments>` in backticks (a bare `ftcgym bench` names the command), bar usage
    lines with [optional], <placeholder> or a|b parts."""
    commands = []
    for span in re.findall(r"`(ftcgym [^`]+)`", text):
        words = shlex.split(span)
        if len(words) > 2 and not any(w.startswith(("[", "<")) or "|" in w for w in words):
            commands.append(span)
    return commands


def test_the_results_table_quotes_commands():
    readme = (ROOT / "README.md").read_text()
    table = readme[readme.index("## Results against the papers"):readme.index("Where we fall short")]
    assert len(quoted_commands(table)) >= 10


def test_the_readme_commands_parse():
    parser = build_parser()
    for command in quoted_commands((ROOT / "README.md").read_text()):
        try:
            parser.parse_args(shlex.split(command)[1:])
        except SystemExit:
            pytest.fail(f"README.md: `{command}` does not parse")


def test_a_misspelt_scenario_fails_to_parse():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["bench", "--scenario", "qp-pitot-abrupt-typo"])
