"""What a user types wrong ends in one line that names it (the flag, the variable, the parameter and its
bound, nan as nan) with exit 2, and no prefix said twice."""

from __future__ import annotations

import pytest

from hil.cli import main


def said(argv: list[str], capsys) -> tuple[int, str]:
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own
        code = exc.code
    return code, capsys.readouterr().err


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["rig", "stop", "--hubb", "x"], "pure-hil: unrecognized arguments: --hubb x (see pure-hil --help)"),
        (["fault", "boom"], "pure-hil fault: argument action: invalid choice: 'boom'"),
        (["run"], "pure-hil run: the following arguments are required: scenario"),
        (["fault", "inject", "sensor.off", "--at", "nan"], "pure-hil fault: argument --at: expected >= 0"),
    ],
)
def test_an_argparse_error_is_one_line(argv, says, capsys):
    code, err = said(argv, capsys)
    assert code == 2 and err.startswith(says) and err.count("\n") == 1, err


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["rig", "status", "--hub", "garbage"], "pure-hil rig: --hub 'garbage': not a zenoh endpoint"),
        (["fault", "clear", "--hub", "garbage"], "pure-hil fault: --hub 'garbage': not a zenoh endpoint"),
        (["serve", "--hub", "tcp/127.0.0.1"], "pure-hil serve: --hub 'tcp/127.0.0.1': not a zenoh endpoint"),
        (
            ["estop", "--hub", "tcp/10.0.0.1:7447"],
            "pure-hil estop: --hub tcp/10.0.0.1:7447: not on this machine",
        ),
    ],
)
def test_a_bad_hub_is_named_as_the_option_not_the_zenoh_config(argv, says, capsys):
    code, err = said(argv, capsys)
    assert code == 2 and err.startswith(says) and err.count("\n") == 1, err
    assert "json5" not in err.lower(), "the zenoh config file is not what was wrong"


def test_a_bad_hub_in_the_environment_is_named_as_the_variable(capsys, monkeypatch):
    monkeypatch.setenv("PURE_HIL_HUB", "garbage")
    code, err = said(["rig", "status"], capsys)
    assert code == 2 and err.startswith("pure-hil rig: PURE_HIL_HUB 'garbage': not a zenoh endpoint"), err


@pytest.mark.parametrize(
    ("param", "says"),
    [
        (
            "sigma=nan",
            "pure-hil fault inject: sensor.noise: sigma = nan is not a number (expected 0 < sigma <=",
        ),
        ("sigma=NaN", "pure-hil fault inject: sensor.noise: sigma = nan is not a number"),
        ("sigma=-inf", "pure-hil fault inject: sensor.noise: sigma = -inf is not a finite number"),
        (
            "sigma=1e308",
            "pure-hil fault inject: sensor.noise: sigma = 1e+308 is out of its bound 0 < sigma <= 6.5535",
        ),
    ],
)
def test_a_bad_fault_parameter_says_what_it_was_once(param, says, capsys):
    code, err = said(
        ["fault", "inject", "sensor.noise", "--param", "channel=imu.pitch", "--param", param], capsys
    )
    assert code == 2 and err.startswith(says) and err.count("\n") == 1, err
    assert err.count("pure-hil") == 1 and err.count("sensor.noise") == 1, "no prefix said twice"


def test_clearing_something_that_is_no_fault_number_exits_2(capsys):
    code, err = said(["fault", "clear", "seven"], capsys)
    assert code == 2 and "pure-hil fault clear: 'seven': expected a fault's number" in err


def _scenario_with(tmp_path, extra: str = "", rider: str = "ref_60kg_180") -> str:
    """balance with another rider or a table added, as a file of its own."""
    from tests.helpers import ROOT

    text = (ROOT / "configs/scenarios/balance.toml").read_text()
    text = text.replace('rider = "configs/riders/ref_60kg_180.toml"', f'rider = "{rider}"')
    path = tmp_path / "mine.toml"
    path.write_text(text + extra)
    return str(path)


def _bench_with(tmp_path, old: str, new: str, shipped: str = "embedded") -> str:
    from tests.helpers import ROOT

    text = (ROOT / f"configs/benches/{shipped}.toml").read_text()
    assert old in text
    path = tmp_path / "bench.toml"
    path.write_text(text.replace(old, new))
    return str(path)


@pytest.mark.parametrize(
    ("case", "field"),
    [
        ("missing rider", 'rider = "{tmp}/nobody.toml": cannot read'),
        ("unknown rider", 'rider = "nobody": no such file here or among the shipped configs'),
        ("misspelt [safety] key", "[safety]: Object contains unknown field `sped` - at `$.speed`"),
        ("unknown bus", "can.interface = 'nosuchbus': not a CAN interface python-can has here"),
        ("hub off this machine", "zenoh.endpoint tcp/0.0.0.0:7999: not on this machine"),
    ],
)
def test_a_bad_file_is_named_by_its_path_and_field_before_anything_runs(case, field, tmp_path, capsys):
    """Each named no file (the rider's path alone, the scenario's name, the bus, the zenoh config) and the
    first two began a run folder first."""
    scenario, bench = "balance", "embedded"
    if case == "missing rider":
        scenario = _scenario_with(tmp_path, rider=str(tmp_path / "nobody.toml"))
    elif case == "unknown rider":
        scenario = _scenario_with(tmp_path, rider="nobody")
    elif case == "misspelt [safety] key":
        scenario = _scenario_with(tmp_path, "\n[safety.speed]\nsped = 1.0\n")
    elif case == "unknown bus":
        bench = _bench_with(tmp_path, 'interface = "socketcan"', 'interface = "nosuchbus"', "vcan")
    else:
        bench = _bench_with(tmp_path, 'mode = "loopback"', 'mode = "loopback"\nendpoint = "tcp/0.0.0.0:7999"')
    out = tmp_path / "run"
    code, err = said(["run", scenario, "--bench", bench, "--out", str(out), "--quiet"], capsys)
    path = scenario if scenario != "balance" else bench
    assert code == 2 and err.startswith(f"pure-hil run: {path}") and err.count("\n") == 1, err
    assert field.format(tmp=tmp_path) in err, err
    assert "json5" not in err and "scenario balance" not in err, "named the file, not another"
    assert not out.exists(), "nothing began"


@pytest.mark.parametrize("given", ["force=100,0", "force=[100,0]", "force=[100, 0]", "force=100, 0"])
def test_a_fault_parameter_of_two_values_is_taken_as_docs_faults_md_writes_it(given, capsys, monkeypatch):
    """`--param force=100,0` was 'Expected `array`, got `str`'; the comma form and JSON both send a list."""
    import json

    import hil.commands.fault as fault_command

    sent = []
    monkeypatch.setattr(
        fault_command, "ask_service", lambda args, key, payload, who: sent.append(payload) or 0
    )
    code, err = said(["fault", "inject", "plant.push", "--param", given, "--param", "height=0.4"], capsys)
    assert code == 0 and err == "", err
    assert json.loads(sent[0])["force"] == [100.0, 0.0] and json.loads(sent[0])["height"] == 0.4


def test_the_live_injection_docs_show_the_forms_the_command_takes():
    from tests.helpers import ROOT

    page = (ROOT / "docs/faults.md").read_text()
    live = page[page.index("## Live injection") :]
    assert "--param force=100,0" in live and "force=[100,0]" in live


@pytest.mark.parametrize("given", ["force=100", "force=100,0,3", "force=[100,0,3]", "force=abc"])
def test_a_fault_parameter_of_the_wrong_shape_names_it_and_its_form(given, capsys):
    code, err = said(["fault", "inject", "plant.push", "--param", given], capsys)
    form = "expected 2 numbers, as force=100,0 or force=[100,0]"
    says = f"pure-hil fault inject: plant.push: --param {given}: {form}"
    assert code == 2 and err.strip() == says, err
