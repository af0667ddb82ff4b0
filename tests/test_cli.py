"""The `pure-hil` command: the plant-only main job runs, reports, and fails cleanly on bad input."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from hil.cli import main


def test_simulate_runs_and_reports(capsys):
    assert main(["simulate", "--duration", "3", "--lean", "10"]) == 0
    out = capsys.readouterr().out
    assert "balanced to the end" in out and "max |speed|" in out and "1200 ticks" in out


def test_simulate_exits_1_when_the_robot_falls(capsys):
    # A 40 deg initial tilt is beyond what the balancer can catch: the run fails, it does not crash.
    assert main(["simulate", "--duration", "3", "--tilt", "40"]) == 1
    assert "FELL: " in capsys.readouterr().out  # a tilt beyond the bound or, in 3-D, a foot on the floor


def test_bad_config_exits_2_naming_file_and_field(tmp_path, capsys):
    bad = tmp_path / "rider.toml"
    bad.write_text('name = "x"\nmass = 70.0\nheight = 3.5\n')
    assert main(["simulate", "--rider", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "$.height" in err and "< 2.3" in err


def test_console_script_is_installed():
    script = Path(sys.executable).with_name("pure-hil")
    out = subprocess.run([str(script), "--help"], capture_output=True, text=True, check=True)
    assert "simulate" in out.stdout


def test_a_spawned_controller_needs_a_shared_bus(capsys):
    assert main(["run", "balance", "--controller", "spawned"]) == 2
    err = capsys.readouterr().err
    assert "controller.where = 'spawned' needs a CAN bus shared between processes" in err
    assert err.count("\n") == 1


def test_a_fault_that_cannot_act_on_the_rig_exits_2_naming_it(tmp_path, capsys):
    scenario = tmp_path / "bad_fault.toml"
    scenario.write_text(
        'name = "bad_fault"\nduration = 0.5\n[[faults]]\nkind = "can.drop"\nmessage = "IMU_RATES"\nat = 0.1\n'
    )
    assert main(["run", str(scenario), "--quiet", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "pure-hil run: fault 0 (can.drop message=IMU_RATES): no message 'IMU_RATES' in the DBC" in err
    assert "Traceback" not in err
    # The run folder says what failed and where.
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["passed"] is False and summary["failure"]["stage"] == "build"
    assert "IMU_RATES" in summary["failure"]["error"]


def test_a_bus_that_cannot_open_says_why_and_what_to_do(monkeypatch, capsys):
    import errno

    import can

    def refuse(**kwargs):
        raise OSError(errno.ENODEV, "No such device")

    monkeypatch.setattr(can, "Bus", refuse)
    assert main(["supervisor", "--can", "socketcan:vcan7"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "socketcan:vcan7 cannot open: no such interface; create it: ip link add dev vcan7 type vcan" in err


def test_an_unexpected_error_is_one_line_and_keeps_its_traceback_in_a_file(monkeypatch, capsys):
    import hil.run.plant_run

    def broken(*args, **kwargs):
        raise ZeroDivisionError("a bug")

    monkeypatch.setattr(hil.run.plant_run, "run_plant", broken)
    assert main(["simulate", "--duration", "0.1"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("pure-hil simulate: unexpected ZeroDivisionError: a bug (traceback: ")
    assert "ZeroDivisionError" in Path(err.split("traceback: ")[1].rstrip(")\n")).read_text()


def test_ctrl_c_ends_a_run_at_the_next_tick_and_writes_its_folder(tmp_path):
    """An operator's Ctrl-C (SIGINT) on a long run: the run stops, is judged on what ran and leaves its whole
    folder (before, the command died with exit 130 and left no summary)."""
    import signal
    import time

    import numpy as np

    scenario = tmp_path / "long.toml"
    scenario.write_text('name = "long"\nrider = "ref_60kg_180"\nduration = 3600.0\n')
    out = tmp_path / "run"
    script = Path(sys.executable).parent / "pure-hil"
    proc = subprocess.Popen(
        [str(script), "run", str(scenario), "--out", str(out), "--quiet"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        while not (out / "trace.npy").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)  # ticking
        proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, output
    assert "stopped at t = " in output and "Traceback" not in output
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stopped_early"] and 0 < summary["simulated"] < 3600
    assert (summary["verdict"], summary["passed"]) == ("STOPPED", False), "stopped early is not passed"
    from hil.outputs.trace_log import LAYOUT

    rows = np.load(out / "trace.npy")
    assert (
        len(rows) == summary["rig"]["ticks"] and abs(rows[-1, LAYOUT.span("t")] - summary["simulated"]) < 1e-6
    )
    assert all((out / name).stat().st_size > 0 for name in ("can.log", "recording.rrd", "plots.png"))


def test_compare_json_prints_one_object_on_stdout_and_its_progress_on_stderr(tmp_path, capsys):
    import msgspec

    from drivers.config import dump_toml
    from hil.pipeline import load_scenario

    short = tmp_path / "speed_limiting.toml"  # a paper task by name, 2 s long
    short.write_bytes(dump_toml(msgspec.structs.replace(load_scenario("speed_limiting"), duration=2.0)))
    argv = ["compare", str(short), "--riders", "s16_mwcu_52kg_167", "--json", "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert [r["law"] for r in data["runs"]] == ["hacs", "ihacs"] and len(data["cells"]) == 8
    assert "s16_mwcu_52kg_167" in captured.err and "seed 0" in captured.err
    assert (tmp_path / "out" / "compare.png").exists()


def test_calibrate_and_adversary_refuse_what_they_cannot_do_in_one_line(capsys):
    assert main(["calibrate", "--fit", "rider.shoe_size"]) == 2
    err = capsys.readouterr().err
    assert "unknown parameter 'rider.shoe_size'" in err and err.count("\n") == 1
    assert main(["adversary", "balance", "--objective", "overspeed"]) == 2
    err = capsys.readouterr().err
    assert "balance has no speed cap" in err and err.count("\n") == 1


def test_version_and_the_bench_help_name_what_is_shipped(capsys):
    from importlib.metadata import version

    from drivers.resources import shipped

    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0 and capsys.readouterr().out.strip() == f"pure-hil {version('pure-hil')}"
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "processes" in shipped("benches")
    assert f"shipped name: {', '.join(shipped('benches'))}" in help_text


def _bad_inputs(tmp: Path) -> list[tuple[list[str], str]]:
    binary = tmp / "binary.toml"
    binary.write_bytes(bytes(range(256)))
    a_file = tmp / "a_file"
    a_file.write_text("")
    huge = tmp / "huge.toml"
    huge.write_text('name = "huge"\nduration = 1e12\n')
    return [
        (["run", str(binary)], f"{binary}: not a TOML text file"),
        (["run", "balance", "--out", str(a_file)], f"--out: {a_file} exists and is not a folder"),
        (["run", "balance", "--out", "/proc/none/run"], "--out: cannot make the folder /proc/none/run"),
        (["run", "balance", "--seed", "-1"], "argument --seed: expected >= 0, got -1"),
        (["simulate", "--duration", "nan"], "argument --duration: expected > 0 and <= 86400, got nan"),
        (["simulate", "--duration", "-1"], "argument --duration: expected > 0 and <= 86400, got -1"),
        (["compare", "balance", "--trials", "0"], "argument --trials: expected >= 1, got 0"),
        (["run", str(huge)], f"{huge}: Expected `float` <= 86400.0 - at `$.duration`"),
        (["fault", "inject", "sensor.bias", "--at", "inf"], "argument --at: expected >= 0"),
    ]


@pytest.mark.parametrize("case", range(9))
def test_bad_input_exits_2_with_one_line_naming_the_option_or_field(case, tmp_path, capsys):
    argv, says = _bad_inputs(tmp_path)[case]
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own usage errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and says in err, err
    assert "unexpected" not in err and "Traceback" not in err
    assert len([line for line in err.splitlines() if "error" in line or says in line]) == 1


def test_the_command_reference_is_the_parser_and_every_option_says_what_it_does():
    import argparse

    from hil.cli import build_parser
    from hil.cli_reference import PAGE, render

    assert PAGE.read_text() == render(), "regenerate with: python -m hil.cli_reference docs"
    commands = next(a for a in build_parser(every=True)._actions if isinstance(a, argparse._SubParsersAction))
    silent = [
        f"{name} {action.option_strings or action.dest}"
        for name, sub in commands.choices.items()
        for action in sub._actions
        if not action.help
    ]
    assert not silent, f"options without help: {silent}"


def test_no_option_says_its_default_twice_in_the_reference():
    """`estop --timeout` read "(default 5) (default 5.0)": its help says it and the page added it again."""
    from hil.cli_reference import render

    rows = [line for line in render().splitlines() if line.startswith("| `")]
    twice = [row for row in rows if row.count("(default") > 1]
    assert not twice, twice
    timeout = next(row for row in rows if row.startswith("| `--timeout` TIMEOUT | s to wait for the super"))
    assert timeout.count("(default 5)") == 1, "the control: the default still said once"
    workers = next(row for row in rows if row.startswith("| `--workers`"))
    assert workers.endswith("(default 1) |"), "a help that does not say its default gets it from the parser"


def table_disagreements(commands: dict, parser) -> list[str]:
    """Where hil/cli.py's COMMANDS and a parser built with every command's options disagree: a sub-command
    not in the table or out of its order, a summary not the table's, an entry whose module lacks its options
    or its handler, a command module under hil/commands/ that no entry names."""
    import argparse
    import importlib
    import pkgutil

    import hil.commands

    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    found = [] if list(sub.choices) == list(commands) else [f"sub-commands {list(sub.choices)}"]
    helps = {a.dest: a.help for a in sub._choices_actions}
    for name, command in commands.items():
        module = importlib.import_module(command.module)
        if not (
            callable(getattr(module, "add_arguments", None)) and callable(getattr(module, "handle", None))
        ):
            found.append(f"{name}: {command.module} has no add_arguments(parser) and handle(args)")
        elif name not in sub.choices or sub.choices[name].get_default("func") is not module.handle:
            found.append(f"{name}: no sub-command that runs {command.module}.handle")
        if helps.get(name) != command.summary:
            found.append(f"{name}: --help says {helps.get(name)!r}")
    named = {command.module for command in commands.values()}
    on_disk = {f"hil.commands.{m.name}" for m in pkgutil.iter_modules(hil.commands.__path__)}
    found += [f"{m} is in no entry of COMMANDS" for m in sorted(on_disk - named - {"hil.commands.common"})]
    return found


def test_the_command_table_and_the_parser_agree():
    from hil.cli import COMMANDS, build_parser

    assert not table_disagreements(COMMANDS, build_parser(every=True))
    assert "simulate" in COMMANDS and "router" in COMMANDS


def test_positive_control_a_command_missing_from_the_table_is_seen(monkeypatch):
    import hil.cli

    full = hil.cli.build_parser(every=True)
    fewer = {name: command for name, command in hil.cli.COMMANDS.items() if name != "rig"}
    assert table_disagreements(fewer, full)[0].startswith("sub-commands [")  # the parser has one more
    monkeypatch.setattr(hil.cli, "COMMANDS", fewer)
    assert table_disagreements(fewer, hil.cli.build_parser(every=True)) == [
        "hil.commands.rig is in no entry of COMMANDS"
    ]
    wrong = {**fewer, "rig": hil.cli.Command("hil.commands.common", "talk to a running serve")}
    assert "rig: hil.commands.common has no add_arguments(parser) and handle(args)" in table_disagreements(
        wrong, full
    )


def test_a_commands_module_is_imported_only_when_it_runs():
    """`pure-hil --help` imports no command's module (it stays fast); a command imports its own and what the
    commands share, no other command's."""
    script = """
import sys
from hil.cli import main

def loaded():
    return sorted(m for m in sys.modules if m.startswith("hil.commands."))

try:
    main(["--help"])
except SystemExit:
    pass
print(loaded(), file=sys.stderr)
main(["fault", "list"])
print(loaded(), file=sys.stderr)
"""
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stderr.splitlines() == ["[]", "['hil.commands.common', 'hil.commands.fault']"], done.stderr
    assert "sensor.bias" in done.stdout  # fault list ran: the catalog
