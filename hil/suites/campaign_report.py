"""A campaign's reports: Markdown (worst cases first, and a coverage campaign's coverage table), JSON and
JUnit XML (hil/suites/html_report.py draws the HTML page from the same pieces)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

import msgspec
import numpy as np

from hil.suites.campaign_run import CaseResult


def worst_first(results: list[CaseResult]) -> list[CaseResult]:
    """Errors, then failures (most failed verdicts first), then passes closest to a fall (peak tilt after
    the release)."""
    return sorted(
        results, key=lambda r: (not r.error, r.passed, -len(r.failed), -r.peak_tilt_after_release_deg)
    )


PEAK_TILT = (
    "peak tilt: the largest chassis tilt after the release, from the first time the robot, released "
    "tilted, came back through upright (never: the whole run's)"
)


def provenance() -> str:
    """What wrote a report: the pure-hil version, and its git commit when it runs from a checkout."""
    from hil.report.folder import commit, versions

    where = commit()
    return f"pure-hil {versions()['pure-hil']}" + (f", commit {where}" if where else " (not a git checkout)")


def supervisors(results: list[CaseResult]) -> str:
    """The supervisor plug(s) that judged the cases, for a report's head (a campaign runs on one bench)."""
    return ", ".join(sorted({r.supervisor for r in results if r.supervisor})) or "none (no case ran)"


def peak_tilt(r: CaseResult) -> str:
    """A case's peak tilt after the release for a table, deg."""
    return f"{r.peak_tilt_after_release_deg:.2f}" + (" (never upright)" if r.release_end is None else "")


def coverage_report(results: list[CaseResult]) -> str:
    """The coverage table (faulty cases by class, then fault-free runs that tripped) and its totals."""
    faulty = [r for r in results if r.role == "faulty"]
    fault_free = [r for r in results if r.role in ("twin", "fault_free")]
    if not faulty and not fault_free:
        return ""
    classes = Counter(r.coverage.label if r.coverage else "ERROR" for r in faulty)
    afters = [r.coverage.after for r in faulty if r.coverage and r.coverage.after]
    ended = Counter(a.ended for a in afters)
    excused = sum(bool(a.excused) for a in afters)
    detected, missed = classes["DETECTED"] + classes["LATE"], classes["MISSED"]
    trips = [r for r in fault_free if r.false_trip or r.error]
    ratios = [r.wall / r.twin_wall for r in faulty if r.twin_wall > 0]
    reactions = [r.coverage.reaction for r in faulty if r.coverage and r.coverage.reaction is not None]
    lines = [
        "## Diagnostic coverage",
        "",
        f"- faulty cases: {len(faulty)}: " + ", ".join(f"{k} {v}" for k, v in sorted(classes.items())),
        "- diagnostic coverage (detected / (detected + missed)): "
        + (f"{detected / (detected + missed):.1%}" if detected + missed else "n/a"),
        f"- reaction: median {np.median(reactions) * 1e3:.1f} ms, max {max(reactions) * 1e3:.1f} ms"
        if reactions
        else "- reaction: none",
        "- after the detection: "
        + ", ".join(f"{k} {v}" for k, v in sorted(ended.items()))
        + (f" ({excused} of the falls unrecoverable, named in the campaign)" if excused else ""),
        f"- false trips: {len(trips)} of {len(fault_free)} fault-free runs",
        f"- wall time of a faulty run vs its twin run just before it on the same worker: max "
        f"{max(ratios):.2f}x"
        if ratios
        else "",
        "",
        "| class | case | cause | reaction ms | departed ms | bound ms | to rest s | peak speed m/s "
        "| peak tilt deg | peak yaw rad/s | modes | drives held by | note |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    order = {"ERROR": 0, "MISSED": 1, "LATE": 2, "DETECTED": 3, "BENIGN": 4}
    for r in sorted(
        faulty,
        key=lambda r: (
            r.coverage is not None and r.coverage.passed,
            order[r.coverage.label if r.coverage else "ERROR"],
            r.case_id,
        ),
    ):
        c = r.coverage
        if c is None:
            lines.append(
                f"| ERROR | {r.case_id} |  |  |  |  |  |  |  |  |  |  "
                f"| {r.error.splitlines()[0][:120] if r.error else ''} |"
            )
            continue
        reaction = "" if c.reaction is None else f"{c.reaction * 1e3:.1f}"
        departed = "" if c.departed is None else f"{c.departed * 1e3:.1f}"
        bound = f"{r.outcome.detect_within * 1e3:.0f}" if r.outcome else ""
        a = c.after
        after = (
            f"{'' if a.to_rest is None else f'{a.to_rest:.1f}'} | {a.peak_speed:.2f} | {a.peak_tilt_deg:.1f} "
            f"| {a.peak_yaw_rate:.1f} | {a.modes} | {a.held_by}"
            if a
            else " |  |  |  |  | "
        )
        note = "; ".join(x for x in (c.note, a and a.excused and f"unrecoverable: {a.excused}") if x)
        lines.append(
            f"| {c.name} | {r.case_id} | {c.cause} | {reaction} | {departed} | {bound} | {after} | {note} |"
        )
    for r in trips:
        why = r.false_trip or r.error.splitlines()[0]
        lines.append(f"| FALSE TRIP | {r.case_id} |  |  |  |  |  |  |  |  |  |  | {why} |")
    return "\n".join(line for line in lines if line is not None) + "\n"


def inconclusive(results: list[CaseResult]) -> str:
    """', N inconclusive' for a report's headline when any case was (the rig itself late)."""
    n = sum(r.verdict == "INCONCLUSIVE" for r in results)
    return f", {n} inconclusive" if n else ""


def report(campaign: str, results: list[CaseResult]) -> str:
    rows = [
        (
            r.verdict,
            r.case_id,
            peak_tilt(r),
            "fell" if r.fallen else "",
            "; ".join(r.safety_events[:2]),
            f"{r.wall:.1f}",
            r.message().replace("\n", " | ")[:160],
        )
        for r in worst_first(results)
    ]
    head = ("verdict", "case", "peak tilt after release deg", "fall", "supervisor", "wall s", "why")
    lines = [
        f"# Campaign {campaign}: {sum(r.passed for r in results)}/{len(results)} passed"
        + inconclusive(results),
        "",
        f"{provenance()}. Judged by the supervisor {supervisors(results)}. Worst first: errors, failures, "
        f"then passes by {PEAK_TILT}.",
        "",
        "| " + " | ".join(head) + " |",
        "|" + "---|" * len(head),
    ]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    coverage = coverage_report(results)
    return "\n".join(lines) + "\n" + ("\n" + coverage if coverage else "")


def report_json(campaign: str, results: list[CaseResult]) -> bytes:
    """The report as data, worst first: each case's verdict and why, and for a faulty case of a coverage
    campaign its class, reaction and what followed the detection (docs/campaigns.md)."""

    def coverage(r: CaseResult) -> dict | None:
        c = r.coverage
        if c is None:
            return None
        return {
            "class": c.name,
            "passed": c.passed,
            "cause": c.cause,
            "reaction": c.reaction,
            "departed": c.departed,
            "bound": r.outcome.detect_within if r.outcome else None,
            "note": c.note,
            "after": msgspec.to_builtins(c.after) if c.after else None,
        }

    cases = [
        {
            "case": r.case_id,
            "scenario": r.scenario,
            "role": r.role,
            "passed": r.passed,
            "verdict": r.verdict,
            "error": r.error,
            "why": "" if r.passed else r.message(),
            "fallen": r.fallen is not None,
            "fall_cause": r.fallen,
            "peak_tilt_after_release_deg": r.peak_tilt_after_release_deg,
            "release_end": r.release_end,
            "safety_events": r.safety_events,
            "wall": r.wall,
            "twin_wall": r.twin_wall,
            "coverage": coverage(r),
            "false_trip": r.false_trip,
            "supervisor": r.supervisor,
        }
        for r in worst_first(results)
    ]
    from hil.report.folder import commit, versions

    summary = {
        "campaign": campaign,
        "version": versions()["pure-hil"],
        "commit": commit(),
        "supervisor": supervisors(results),
        "passed": sum(r.passed for r in results),
        "inconclusive": sum(bool(r.inconclusive) and not r.error for r in results),
        "total": len(results),
    }
    return msgspec.json.format(msgspec.json.encode({**summary, "cases": cases}), indent=2)


def junit_xml(campaign: str, results: list[CaseResult]) -> bytes:
    suite = ET.Element(
        "testsuite",
        name=campaign,
        tests=str(len(results)),
        failures=str(sum(r.verdict == "FAIL" for r in results)),
        errors=str(sum(bool(r.error) for r in results)),
        skipped=str(sum(r.verdict == "INCONCLUSIVE" for r in results)),
        time=f"{sum(r.wall for r in results):.3f}",
    )
    judged_by = ET.SubElement(suite, "properties")
    ET.SubElement(judged_by, "property", name="supervisor", value=supervisors(results))
    for r in results:
        case = ET.SubElement(
            suite,
            "testcase",
            classname=f"{campaign}.{Path(r.scenario).stem}",
            name=r.case_id,
            time=f"{r.wall:.3f}",
        )
        props = ET.SubElement(case, "properties")
        for v in r.verdicts:
            ET.SubElement(props, "property", name=v["criterion"], value=f"{v['value']:.6g}")
        if r.error:
            ET.SubElement(case, "error", message=r.error.splitlines()[0][:200]).text = r.error
        elif r.inconclusive:
            # Neither passed nor failed: JUnit's `skipped`, its message saying why.
            message = r.message()
            ET.SubElement(case, "skipped", message=message.splitlines()[0][:200]).text = message
        elif not r.passed:
            message = r.message()
            ET.SubElement(case, "failure", message=message.splitlines()[0][:200]).text = message
    ET.indent(suite)
    return ET.tostring(suite, encoding="utf-8", xml_declaration=True)
