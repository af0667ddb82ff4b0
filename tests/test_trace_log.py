"""trace.npy by column name: the rig writes its rows and the run reads them back where the one declaration
(hil/outputs/trace_log.py COLUMNS) puts each column, so a declaration whose columns moved is written and
read as its names say; a fixed index left anywhere in the writer or the readers fails here."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hil.outputs.trace_log import COLUMNS, LAYOUT, TOLD, Column, Layout, TraceLog
from hil.run import loop
from plant.core import Truth

TRUTH = Truth(  # every column's value distinct, so a value in another's column shows
    t=0.125,
    velocity=(1.1, 1.2),
    tilt=(2.1, 2.2),
    lean=(3.1, 3.2),
    position=(4.1, 4.2),
    yaw_rate=5.1,
    ball_rate=(6.1, 6.2),
    motor_torque=(7.1, 7.2, 7.3),
    resting=False,
    powered=True,
    tilt_rate=(0.0, 0.0),
    ball_angle=(0.0, 0.0),
    yaw=0.0,
    hip_torque=(0.0, 0.0),
    seat_wrench=(0.0,) * 6,
    fallen=None,
)
RIG = SimpleNamespace(
    port=SimpleNamespace(safety_state=3), supervisor=SimpleNamespace(observed_speed=lambda: 8.5)
)
COMMAND_SPEED, TILT_COMMAND = (9.1, 9.2), (10.1, 10.2)
EXPECTED = {
    "t": 0.125,
    "velocity.forward": 1.1,
    "velocity.left": 1.2,
    "tilt.pitch": 2.1,
    "tilt.roll": 2.2,
    "lean.pitch": 3.1,
    "lean.roll": 3.2,
    "position.x": 4.1,
    "position.y": 4.2,
    "yaw_rate": 5.1,
    "ball_rate.pitch": 6.1,
    "ball_rate.roll": 6.2,
    "motor_torque.1": 7.1,
    "motor_torque.2": 7.2,
    "motor_torque.3": 7.3,
    "safety_state": 3.0,
    "safety_speed": 8.5,
    "powered": 1.0,
    "resting": 0.0,
    "command_speed.pitch": 9.1,
    "command_speed.roll": 9.2,
    "tilt_command.pitch": 10.1,
    "tilt_command.roll": 10.2,
}
"""What the row of TRUTH, RIG and the telemetry holds in each column, by name."""


def groups(columns: tuple[Column, ...]) -> list[list[Column]]:
    """The columns by group (velocity.forward and velocity.left one group), in the declared order."""
    grouped: list[list[Column]] = []
    for column in columns:
        if grouped and grouped[-1][0].name.partition(".")[0] == column.name.partition(".")[0]:
            grouped[-1].append(column)
        else:
            grouped.append([column])
    return grouped


def moved() -> tuple[Column, ...]:
    """The declaration with every column moved: the rig's groups and the telemetry's each turned by one (t
    last, the others one column earlier; tilt_command before command_speed)."""
    rig, told = groups(COLUMNS[: LAYOUT.telemetry]), groups(COLUMNS[LAYOUT.telemetry :])
    return tuple(c for part in (rig, told) for group in part[1:] + part[:1] for c in group)


def write_and_read(layout: Layout, tmp_path) -> tuple[np.ndarray, dict]:
    """Two ticks through the writer, the log (streamed to a file) and the reader the run uses."""
    log = TraceLog(2, tmp_path / "trace.npy", layout=layout)
    for _ in range(2):
        log.append(loop._row(TRUTH, RIG, layout.order(loop.ROW_GROUPS)))  # type: ignore[arg-type]
    log.telemetry(0, COMMAND_SPEED, TILT_COMMAND)
    log.telemetry(1, COMMAND_SPEED, TILT_COMMAND)
    rows = np.array(log.close())
    return rows, loop._series(rows, layout)


@pytest.mark.parametrize("declaration", [COLUMNS, moved()], ids=["shipped", "every column moved"])
def test_each_column_is_written_and_read_where_its_declaration_puts_it(declaration, tmp_path):
    layout = Layout(declaration)
    rows, series = write_and_read(layout, tmp_path)
    assert rows.shape == (2, len(COLUMNS))
    # The file, by the declaration's names.
    assert {c.name: rows[1, i] for i, c in enumerate(declaration)} == EXPECTED
    # The run's Trace, by its fields.
    assert series.keys() == {c.name.partition(".")[0] for c in COLUMNS}
    for group, values in series.items():
        expected = [v for name, v in EXPECTED.items() if name.partition(".")[0] == group]
        assert np.array_equal(np.atleast_1d(values[1]), expected), group
    assert (series["safety_state"].dtype, series["powered"].dtype) == (np.int8, bool)


def test_the_moved_declaration_moves_every_column():
    """The control of the test above: each column's index differs from the shipped one, so a fixed index
    anywhere reads another column there."""
    shipped = {c.name: i for i, c in enumerate(COLUMNS)}
    assert sorted(c.name for c in moved()) == sorted(shipped)
    assert all(shipped[c.name] != i for i, c in enumerate(moved()))
    assert Layout(moved()).order(loop.ROW_GROUPS) is not None and Layout(moved()).order(TOLD) is not None


def test_the_shipped_declaration_is_written_in_order_at_no_cost_to_the_tick():
    """The rig's writer and the telemetry's produce the shipped declaration's order: no reordering per tick,
    and the bytes of trace.npy as before."""
    assert LAYOUT.order(loop.ROW_GROUPS) is None and LAYOUT.order(TOLD) is None


@pytest.mark.parametrize(
    "declaration, error",
    [
        (
            (
                Column("t", "s", ""),
                Column("tilt.pitch", "rad", ""),
                Column("t2", "s", ""),
                Column("tilt.roll", "rad", ""),
            ),
            "trace column 'tilt.roll': its group 'tilt' is not side by side",
        ),
        (
            (*COLUMNS[LAYOUT.telemetry :], *COLUMNS[: LAYOUT.telemetry]),
            "the controller's telemetry ('command_speed', 'tilt_command') must be the last columns",
        ),
        ((Column("t", "s", ""),), "no trace column 'command_speed' (known: t)"),
    ],
    ids=["a group split", "the telemetry first", "no telemetry"],
)
def test_a_declaration_the_writers_cannot_fill_is_refused_at_once(declaration, error):
    with pytest.raises(ValueError) as refused:
        Layout(declaration)
    assert error in str(refused.value)


def test_a_writer_that_leaves_a_column_unwritten_is_refused():
    with pytest.raises(ValueError, match="t, velocity fill neither the rig's columns nor the telemetry's"):
        LAYOUT.order(("t", "velocity"))
    with pytest.raises(ValueError, match="fill neither"):
        LAYOUT.order(loop.ROW_GROUPS[:-1])
