"""CSV time columns with a zone, bad time cells by line, and units lines not read."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from aeroid.errors import DataFormatError
from aeroid.io.data import load_flight_test


def _csv(tmp: Path, text: str) -> Path:
    p = tmp / "a.csv"
    p.write_text(text)
    return p


@pytest.mark.parametrize(
    "cells",
    [
        ("2024-05-01T10:00:00.25Z", "2024-05-01T10:00:00.50Z", "2024-05-01T10:00:01Z"),
        # an offset is read in UTC: 12:00 at +02:00 is 10:00 Z
        ("2024-05-01T12:00:00.25+02:00", "2024-05-01T10:00:00.50Z", "2024-05-01T11:00:01+01:00"),
    ],
)
def test_iso_times_with_a_zone_become_seconds(tmp_path: Path, cells: tuple[str, ...]) -> None:
    p = _csv(tmp_path, "time,x\n" + "".join(f"{c},{i}\n" for i, c in enumerate(cells)))
    np.testing.assert_allclose(load_flight_test(p).time, [0.0, 0.25, 0.75], rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("bad", "what"),
    [("garbage", "without a zone"), ("2024-05-01T10:00:00.5Z", "without a zone")],
)
def test_a_bad_time_cell_is_named_by_line_and_column(tmp_path: Path, bad: str, what: str) -> None:
    p = _csv(
        tmp_path,
        f"# a note\ntime,x\n2024-05-01T10:00:00.25,1\n{bad},2\n2024-05-01T10:00:01,3\n",
    )
    with pytest.raises(DataFormatError, match=rf"row 4, column 'time': not an ISO 8601 .*{what}"):
        load_flight_test(p)


def test_a_naive_cell_in_a_zoned_column_is_named(tmp_path: Path) -> None:
    p = _csv(
        tmp_path, "time,x\n2024-05-01T10:00:00Z,1\n2024-05-01T10:00:01Z,2\n2024-05-01T10:00:02,3\n"
    )
    with pytest.raises(DataFormatError, match=r"row 4, column 'time': .* with a zone"):
        load_flight_test(p)


@pytest.mark.parametrize(
    ("head", "line", "why"),
    [
        ('# units: {"alpha": "deg"}\n# units: {"q": "deg/s"}\ntime,alpha,q\n', 2, "a second"),
        (
            '# units: {"alpha": "deg"}\ntime,alpha,q\n# units: {"q": "deg/s"}\n',
            3,
            "it is after the",
        ),
        ('#units: {"q": "deg/s"}\ntime,alpha,q\n', 1, "written '#units:'"),
        ('# Units: {"q": "deg/s"}\ntime,alpha,q\n', 1, "written '# Units:'"),
    ],
)
def test_a_units_line_not_read_warns_naming_its_line(
    tmp_path: Path, head: str, line: int, why: str
) -> None:
    p = _csv(tmp_path, head + "0,1,2\n0.1,2,3\n")
    with pytest.warns(UserWarning, match=rf"a.csv: line {line}: units comment not read \({why}"):
        d = load_flight_test(p)
    assert "q" not in d.units
    assert d.units.get("alpha") == ("deg" if '"alpha"' in head else None)


def test_one_units_line_says_nothing_more(tmp_path: Path) -> None:
    p = _csv(tmp_path, '# units: {"alpha": "deg", "q": "deg/s"}\ntime,alpha,q\n0,1,2\n0.1,2,3\n')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert dict(load_flight_test(p).units) == {"alpha": "deg", "q": "deg/s"}
