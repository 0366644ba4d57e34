"""hil.analysis.measure.clocks: the controller's stamps on the plant's clock, only when the
estimates prove the clocks differ; the plant's own stamps and the "no stamp" zeros never move."""

from __future__ import annotations

import numpy as np

from hil.analysis.measure.clocks import CONTROLLER_CLOCK, to_plant_clock
from hil.folder.clocks import read_track
from runtime.clocksync import CLOCK_FILE, COLUMNS

OFFSET = 4_900_000_000  # plant minus controller


def _write_track(folder, rows) -> None:
    lines = [",".join(COLUMNS)]
    for t4, best, unc in rows:
        lines.append(f"{t4 - 900},{t4 + OFFSET - 600},{t4 + OFFSET - 500},{t4},0,0,{best},{unc}")
    (folder / CLOCK_FILE).write_text("\n".join(lines) + "\n")


def _tables():
    ticks = {
        "deadline_ns": np.array([1_000, 2_000, 3_000], np.int64),
        "state_recv_ns": np.array([1_100, 0, 3_100], np.int64),  # 0: no stamp
        "state_send_ns": np.array([7_000, 8_000, 9_000], np.int64),  # the plant's
    }
    return {"ticks": ticks, "cmd_rx": {"recv_ns": np.array([5], np.int64)}}


def test_controller_stamps_move_by_the_estimate_in_force_and_nothing_else_does(tmp_path):
    _write_track(tmp_path, [(1_500, OFFSET + 40, 200), (2_500, OFFSET + 10, 150)])
    t = _tables()
    to_plant_clock(t, tmp_path)
    # Before the second estimate (t4 = 2500) the first holds; the first also covers earlier.
    assert t["ticks"]["deadline_ns"].tolist() == [
        1_000 + OFFSET + 40,
        2_000 + OFFSET + 40,
        3_000 + OFFSET + 10,
    ]
    assert t["ticks"]["state_recv_ns"].tolist() == [1_100 + OFFSET + 40, 0, 3_100 + OFFSET + 10]
    assert t["ticks"]["state_send_ns"].tolist() == [7_000, 8_000, 9_000]
    assert t["cmd_rx"]["recv_ns"].tolist() == [5]
    facts = read_track(tmp_path).facts()
    assert facts["converted"] and facts["uncertainty_ns_max"] == 200


def test_one_host_estimates_and_none_convert_nothing(tmp_path):
    for rows in ([(1_500, 80, 200), (2_500, -30, 150)], []):
        _write_track(tmp_path, rows)
        t = _tables()
        to_plant_clock(t, tmp_path)
        assert t["ticks"]["deadline_ns"].tolist() == [1_000, 2_000, 3_000]
    (tmp_path / CLOCK_FILE).unlink()
    assert read_track(tmp_path).facts() == {"estimates": 0, "related": False}


def test_every_converted_column_is_a_controller_stamp():
    from protocol.hoplog import CONTROLLER_TABLES, PLANT_TABLES

    tables = {**dict(CONTROLLER_TABLES), **dict(PLANT_TABLES)}
    for table, columns in CONTROLLER_CLOCK.items():
        assert set(columns) <= set(tables[table]), table
    # The plant's stamps carried back in a State are never converted.
    assert not {"state_sample_ns", "state_send_ns"} & set(CONTROLLER_CLOCK["ticks"])
