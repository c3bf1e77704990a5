"""What a user gets wrong on the command line ends in one line naming it and exit status 2, never a traceback."""
import pytest

from ftcgym.cli import main


def run_cli(argv, capsys) -> tuple[int, list[str]]:
    try:
        status = main(argv)
    except SystemExit as stop:          # argparse's usage errors
        status = stop.code
    return status, [line for line in capsys.readouterr().err.splitlines() if line.strip()]


@pytest.fixture()
def files(tmp_path):
    (tmp_path / "broken.yaml").write_text("name: x\nscenarios: [1, 2\n")
    (tmp_path / "binary.yaml").write_bytes(b"\xff\xfe\x00garbage")
    (tmp_path / "model.zip").write_text("not a zip")
    return tmp_path


@pytest.mark.parametrize("argv, expected", [
    (["bench", "--seed", "-3"], "argument --seed: expected an integer >= 0, got '-3'"),
    (["bench", "--episodes", "0"], "argument --episodes: expected an integer >= 1, got '0'"),
    (["bench", "--scenario", "quad-rotor-loss-hover", "--detector-kwargs", '{"bad": 1}', "--out", "{tmp}/o"],
     "ftcgym bench: scenario 'quad-rotor-loss-hover': loe_kalman: unknown field(s) ['bad']"),
    (["bench", "--scenario", "quad-hover", "--env-kwargs", '{"physics_hz": 1e7}', "--out", "{tmp}/o"],
     "ftcgym bench: scenario 'quad-hover': physics_hz: must be in [50, 20000], got 10000000.0"),
    (["bench", "--scenario", "quad-hover", "--out", "/dev/null/x"],
     "ftcgym bench: --out /dev/null/x: a file is in the way; the output folder must be a folder, or not exist yet"),
    (["sweep", "{tmp}/broken.yaml"], "broken.yaml: not valid YAML at line 3, column 1"),
    (["sweep", "{tmp}/binary.yaml"], "binary.yaml: not a text file"),
    (["sweep", "{tmp}/missing.yaml"], "ftcgym sweep: config: no file"),
    (["train", "--config", "{tmp}/broken.yaml"], "broken.yaml: not valid YAML at line 3, column 1"),
    (["evaluate", "{tmp}/model.zip"], "model.zip: not a model saved by ftcgym train or SB3 (BadZipFile"),
    (["evaluate", "{tmp}/nothing.zip"], "ftcgym evaluate: model: no file"),
    (["airdata-study", "--scenario", "nope"], "argument --scenario: scenario: unknown name 'nope'"),
    (["thresholds", "--scenario", "nope"], "argument --scenario: scenario: unknown name 'nope'"),
    (["perf", "--steps", "-5"], "argument --steps: expected an integer >= 1, got '-5'"),
    (["replay", "x.ulg", "--detector", "loe_kalman", "--rate", "1e9"],
     "argument --rate: expected a number of Hz in (0, 10000], got '1e9'"),
    (["bench", "--scenario", "quad-hover", "quad-hover", "--out", "{tmp}/o"],
     "ftcgym bench: scenarios: 'quad-hover' is given twice; give each once"),
    (["bench", "--scenario", "quad-hover", "--policy", "nominal", "--policy", "nominal", "--out", "{tmp}/o"],
     "ftcgym bench: policies: 'nominal' is given twice; give each once"),
    (["bench", "--scenario", "quad-hover", "--policy", "ftc-spin", "--out", "{tmp}/o"],
     "ftcgym bench: scenario 'quad-hover': policy 'ftc-spin' reads the 'loe_kalman' detector, which this scenario's "
     "env is not wrapped with (no detector); give --detector loe_kalman or a scenario that has it"),
])
def test_user_errors_end_in_one_line_and_status_2(argv, expected, files, capsys):
    status, lines = run_cli([arg.replace("{tmp}", str(files)) for arg in argv], capsys)
    assert status == 2
    assert len(lines) == 1 or lines[0].startswith("usage:")      # argparse prints its usage line first
    assert expected in lines[-1] and "Traceback" not in "\n".join(lines)


def test_the_traceback_is_there_when_asked(files, monkeypatch):
    monkeypatch.setenv("FTCGYM_TRACEBACK", "1")
    with pytest.raises(ValueError, match="not valid YAML"):
        main(["sweep", str(files / "broken.yaml")])


def test_every_option_of_every_command_has_a_help_text():
    from ftcgym.cli import build_parser
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    missing = [f"{name} {'/'.join(action.option_strings) or action.dest}"
               for name, sub in commands.items() for action in sub._actions
               if action.help is None and action.dest != "help"]
    assert missing == []


def test_a_repeated_option_adds_to_the_list():
    from ftcgym.cli import build_parser
    args = build_parser().parse_args(["bench", "--scenario", "quad-hover", "--scenario", "quad-square", "--policy",
                                      "nominal", "--policy", "ftc-spin", "oracle-spin"])
    assert [s.name for s in args.scenario] == ["quad-hover", "quad-square"]
    assert args.policy == ["nominal", "ftc-spin", "oracle-spin"]


def test_ctrl_c_is_one_line_and_status_130(monkeypatch, capsys):
    import ftcgym.cli.perf as perf

    def interrupted(args, argv):
        raise KeyboardInterrupt
    monkeypatch.setattr(perf, "run", interrupted)
    status, lines = run_cli(["perf"], capsys)
    assert status == 130 and lines == ["ftcgym perf: interrupted"]
