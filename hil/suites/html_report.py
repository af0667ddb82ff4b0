"""report.html: a campaign on one page for the lab's nightly page: what wrote it (version, commit), the
table worst first (errors, failures, then passes closest to a fall by their peak tilt after the release),
each case's verdicts, its plot, and links to its run folder, summary and recording; the coverage table of a
coverage campaign. Links are relative to the report's folder, so the folder can be served or copied as it
is."""

from __future__ import annotations

import html
import time
from pathlib import Path

from hil.run.measurements import with_unit
from hil.suites.campaign import (
    PEAK_TILT,
    CaseResult,
    coverage_report,
    peak_tilt,
    provenance,
    supervisors,
    worst_first,
)

STYLE = """
body { font: 14px system-ui, sans-serif; margin: 1.5em; }
table { border-collapse: collapse; }
th, td { border-bottom: 1px solid #ddd; padding: 6px 8px; text-align: left; vertical-align: top; }
.ERROR { background: #f8d7da; } .FAIL { background: #fff3cd; }
li.failed { color: #a00; font-weight: 600; }
img { width: 320px; border: 1px solid #ccc; }
pre { background: #f6f6f6; padding: 1em; overflow-x: auto; }
"""


def html_report(campaign: str, results: list[CaseResult], folder: Path) -> str:
    """The page for `results`, whose case folders are `folder/CASE` (the campaign's --out)."""
    passed = sum(r.passed for r in results)
    rows = "\n".join(_row(r, folder) for r in worst_first(results))
    coverage = coverage_report(results)
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Campaign {html.escape(campaign)}</title>
<style>{STYLE}</style></head>
<body>
<h1>Campaign {html.escape(campaign)}: {passed}/{len(results)} passed</h1>
<p>Written {time.strftime("%Y-%m-%d %H:%M:%S")} by {html.escape(provenance())}. Judged by the supervisor
{html.escape(supervisors(results))}. Worst first: errors, failures, then passes closest to a fall by
{html.escape(PEAK_TILT)}.</p>
<table>
<tr><th>verdict</th><th>case</th><th>peak tilt after release</th><th>supervisor</th><th>wall</th>
<th>verdicts</th><th>plot</th></tr>
{rows}
</table>
{f"<h2>Diagnostic coverage</h2><pre>{html.escape(coverage)}</pre>" if coverage else ""}
</body></html>
"""


def _row(r: CaseResult, folder: Path) -> str:
    verdict = "ERROR" if r.error else "PASS" if r.passed else "FAIL"
    case = html.escape(r.case_id)
    links = [f'<a href="{case}/">{case}</a>']
    for name, label in (("summary.json", "summary"), ("recording.rrd", "recording")):
        if (folder / r.case_id / name).exists():
            links.append(f'<a href="{case}/{name}">{label}</a>')
    items = [
        f'<li class="{"passed" if v["passed"] else "failed"}">{html.escape(v["criterion"])}: '
        f"{with_unit(format(v['value'], '.4g'), html.escape(v['units']))} "
        f"(limit {html.escape(str(v['limit']))})"
        f"{' — ' + html.escape(v['note']) if v.get('note') else ''}</li>"
        for v in r.verdicts
    ]
    if r.error:
        items.insert(0, f'<li class="failed">error: {html.escape(r.error)}</li>')
    if r.coverage is not None:
        items.insert(0, f"<li>{html.escape(r.coverage.label)} {html.escape(r.coverage.cause or '')}</li>")
    plot = ""
    if (folder / r.case_id / "plots.png").exists():
        plot = f'<a href="{case}/plots.png"><img src="{case}/plots.png" alt="{case}" loading="lazy"></a>'
    supervisor = "<br>".join(html.escape(e) for e in r.safety_events[:3])
    return (
        f'<tr class="{verdict}"><td>{verdict}{" (fell)" if r.fallen else ""}</td>'
        f"<td>{' · '.join(links)}</td><td>{peak_tilt(r)} deg</td><td>{supervisor}</td>"
        f"<td>{r.wall:.1f} s</td><td><ul>{''.join(items)}</ul></td><td>{plot}</td></tr>"
    )
