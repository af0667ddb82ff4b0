"""A supervisor's rules reach its plug whole (drivers/rules.py): the bench's file with a scenario's `[safety]`
overrides, checked by the type the plug registers, and the rig judges by the few limits it reads of them,
whichever supervisor ran (issue 38: hil/ imports nothing from safety/)."""

from __future__ import annotations

import msgspec
import pytest

from drivers.config import ConfigError
from drivers.rules import JudgedRules, MotionLimits, SpeedLimits, StopLimits
from hil.bench.bench import load_bench
from hil.cli import main
from hil.run.build import judged_rules, supervisor_rules
from hil.run.scenario import Scenario
from safety.config import SupervisorConfig
from tests.zenoh_helpers import private_bench


def _supervised(bench, **changes):
    return msgspec.structs.replace(bench, supervisor=msgspec.structs.replace(bench.supervisor, **changes))


def _with_plugin(plugin: str):
    return _supervised(load_bench("embedded"), plugin=plugin)


def test_the_judge_reads_the_scenarios_overrides_of_the_benches_rules():
    scenario = Scenario(name="s", safety={"speed": {"absolute_cap": 1.2}, "motion": {"tilt_limit_deg": 15}})
    rules = judged_rules(load_bench("embedded"), scenario)
    assert (rules.speed.absolute_cap, rules.motion.tilt_limit_deg) == (1.2, 15.0)
    # The rest are the bench file's (configs/safety/default.toml), which the reference's defaults equal.
    assert rules.speed.margin == SupervisorConfig().speed.margin
    assert judged_rules(load_bench("embedded"), Scenario(name="s")) == JudgedRules()


def test_the_plug_gets_the_file_with_the_overrides_key_by_key():
    rules = supervisor_rules(load_bench("embedded"), Scenario(name="s", safety={"speed": {"window": 0.4}}))
    config = msgspec.convert(rules, SupervisorConfig)
    assert config.speed.window == 0.4
    assert config.speed.absolute_cap == SupervisorConfig().speed.absolute_cap  # the section's other keys kept


def test_a_misspelt_rule_is_refused_naming_where_it_is_and_the_field_before_a_run(tmp_path):
    bench = load_bench("embedded")
    with pytest.raises(ConfigError, match=r"^scenario s \[safety\]: .*absolut_cap.*\$\.speed"):
        supervisor_rules(bench, Scenario(name="s", safety={"speed": {"absolut_cap": 1.0}}))
    with pytest.raises(ConfigError, match=r"unknown field `sped`"):
        supervisor_rules(bench, Scenario(name="s", safety={"sped": {"absolute_cap": 1.0}}))
    with pytest.raises(ConfigError, match=r"^--safety: \[safety\.minimal\]: minimal is not a section"):
        not_a_table = Scenario(name="s", safety={"minimal": 5})  # type: ignore[dict-item]
        supervisor_rules(bench, not_a_table, overrides="--safety")
    # A bad rules file is the file's fault, whatever the scenario says.
    rules = tmp_path / "rules.toml"
    rules.write_text("[speed]\nabsolute_cap = -1.0\n")
    bad = msgspec.structs.replace(
        bench, supervisor=msgspec.structs.replace(bench.supervisor, config=str(rules))
    )
    with pytest.raises(ConfigError, match=rf"^{rules}: .*\$\.speed\.absolute_cap"):
        supervisor_rules(bad, Scenario(name="s", safety={"speed": {"margin": 0.1}}))


def test_a_lab_supervisors_limits_the_rig_judges_by_are_checked_too(tmp_path):
    """No rules type registered: still, a limit the judge reads must be a number (else the run's verdict
    would end in a traceback)."""
    rules = tmp_path / "lab.toml"
    rules.write_text('[speed]\nabsolute_cap = "fast"\n')
    lab = _supervised(load_bench("embedded"), plugin="minimal", config=str(rules))
    with pytest.raises(ConfigError, match=rf"^{rules}: Expected `float`"):
        judged_rules(lab, Scenario(name="s"))


def test_an_external_supervisors_rules_are_checked_when_the_run_is_built(tmp_path):
    """Nobody the rig starts is handed them, but the run is judged by them: a misspelt override fails the
    run by name instead of being judged by the defaults."""
    from hil.pipeline import run

    bench = private_bench(supervisor="external")  # its own hub port: tests never take fixed ports
    scenario = Scenario(name="s", duration=0.1, safety={"speed": {"absolut_cap": 1.2}})
    failure = run(scenario, bench).trace.failure
    assert failure is not None and failure.config and "absolut_cap" in failure.error, failure


def test_a_limit_the_rig_reads_is_checked_when_the_scenario_loads():
    with pytest.raises(ValueError, match=r"safety: Expected `float`.*\$\.speed\.absolute_cap"):
        Scenario(name="s", safety={"speed": {"absolute_cap": "fast"}})
    with pytest.raises(ValueError, match=r"> 0\.0 - at `\$\.motion\.tilt_limit_deg`"):
        Scenario(name="s", safety={"motion": {"tilt_limit_deg": -1}})


def test_a_supervisor_without_a_registered_rules_type_gets_its_section_unchecked():
    """A lab's supervisor keeps its own keys (tests/minimal_supervisor.py reads `[safety.minimal]`); the
    control is the reference, whose registered type refuses the same keys."""
    scenario = Scenario(name="s", safety={"minimal": {"max_speed": 0.5}})
    assert supervisor_rules(_with_plugin("minimal"), scenario)["minimal"] == {"max_speed": 0.5}
    with pytest.raises(ConfigError, match="minimal"):
        supervisor_rules(_with_plugin("reference"), scenario)


def test_each_limit_is_declared_once():
    """The reference's sections extend the judged ones: the same fields, the same defaults."""
    for judged, reference in (
        (SpeedLimits, type(SupervisorConfig().speed)),
        (StopLimits, type(SupervisorConfig().stop)),
        (MotionLimits, type(SupervisorConfig().motion)),
    ):
        assert issubclass(reference, judged)
        assert not set(judged.__struct_fields__) & set(reference.__annotations__), reference


def test_pure_hil_supervisor_refuses_bad_overrides_by_flag(capsys):
    argv = ["supervisor", "--can", "socketcan:vcan-nonexistent"]
    assert main([*argv, "--safety", "{not json"]) == 2
    assert "--safety" in capsys.readouterr().err
    assert main([*argv, "--safety", '{"speed": {"absolute_cap": "fast"}}']) == 2
    assert "absolute_cap" in capsys.readouterr().err
    assert main([*argv, "--safety", '{"minimal": 5}']) == 2  # a section that is not a table
    assert "--safety: Expected `object`" in capsys.readouterr().err
    assert main([*argv, "--safety", '{"speed": {"absolut_cap": 1}}']) == 2
    assert "--safety: Object contains unknown field `absolut_cap`" in capsys.readouterr().err
