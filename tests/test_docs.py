"""The commands the README and the results page quote must still parse: scenario, policy and detector names,
options and JSON arguments are all checked by the CLI's parser (nothing is flown). The README stays short."""
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
    results = (ROOT / "docs" / "results.md").read_text()
    table = results[results.index("## Results against the papers"):results.index("Where we fall short")]
    assert len(quoted_commands(table)) >= 10


@pytest.mark.parametrize("page", ["README.md", "docs/results.md", "docs/benchmark.md", "docs/howto/video.md"])
def test_the_quoted_commands_parse(page):
    parser = build_parser()
    for command in quoted_commands((ROOT / page).read_text()):
        try:
            parser.parse_args(shlex.split(command)[1:])
        except SystemExit:
            pytest.fail(f"{page}: `{command}` does not parse")


def test_the_readme_is_short_and_points_into_the_docs():
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    for page in ("docs/concepts.md", "docs/results.md", "docs/howto/own-detector.md", "docs/howto/own-policy.md",
                 "docs/references.md"):
        assert f"]({page}" in readme and (ROOT / page).exists()


def test_a_misspelt_scenario_fails_to_parse():
    with pytest.raises(SystemExit):
        build_parser().parse_args(["bench", "--scenario", "qp-pitot-abrupt-typo"])


def test_the_training_howto_shows_the_shipped_config():
    """The YAML on the training how-to is the shipped rotor-loss-recovery config, character for character."""
    page = (ROOT / "docs" / "howto" / "train.md").read_text()
    shown = re.search(r"```yaml\n(.*?)```", page, re.S).group(1)
    shipped = (ROOT / "ftcgym" / "training" / "configs" / "rotor-loss-recovery.yaml").read_text()
    assert shown.strip() == shipped.strip()
