"""Campaigns: scenarios x riders x control laws x fault sets x seeds, each combination a lockstep run with a
verdict.

A campaign file (`configs/campaigns/*.toml`, docs/campaigns.md) names the scenarios, the riders (none: each
scenario's own), the control laws (none: each scenario's own), the fault sets (each a name, a list of faults
with their expected reactions and operator actions; a fault-free baseline unless `baseline = false`) and the
seeds. With a `[coverage]` table it is a diagnostic coverage campaign (hil/suites/coverage.py): each faulty
case is classed against its fault-free twin (DETECTED, BENIGN, MISSED, LATE), fault sets need no expectations,
and every fault-free case, including the `[[fault_free]]` runs, counts a false trip if the supervisor acts.
`pure-hil campaign FILE --workers N` runs the cases in parallel processes and writes a report (worst cases
first, also as JSON) and JUnit XML; the pytest plugin collects the same cases as test items
(hil/suites/pytest_plugin.py).

This module is the campaigns' one import path; its parts: campaign_file.py (the file, its cases),
campaign_run.py (running and judging them) and campaign_report.py (the reports).
"""

from hil.suites.campaign_file import (
    Campaign,
    Case,
    FaultFree,
    FaultSetEntry,
    Law,
    Role,
    expand,
    load_campaign,
)
from hil.suites.campaign_report import (
    PEAK_TILT,
    coverage_report,
    inconclusive,
    junit_xml,
    peak_tilt,
    provenance,
    report,
    report_json,
    supervisors,
    worst_first,
)
from hil.suites.campaign_run import (
    CaseResult,
    distributable,
    judge,
    quiet_cases,
    run_campaign,
    run_case,
    run_pool,
)

__all__ = [
    "PEAK_TILT",
    "Campaign",
    "Case",
    "CaseResult",
    "FaultFree",
    "FaultSetEntry",
    "Law",
    "Role",
    "coverage_report",
    "distributable",
    "expand",
    "inconclusive",
    "judge",
    "junit_xml",
    "load_campaign",
    "peak_tilt",
    "provenance",
    "quiet_cases",
    "report",
    "report_json",
    "run_campaign",
    "run_case",
    "run_pool",
    "supervisors",
    "worst_first",
]
