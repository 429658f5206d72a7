"""CSV errors name the file line an editor shows; a `# units:` line naming no column warns."""

from __future__ import annotations

import warnings

import pytest

import aeroid
from aeroid import DataFormatError, load_flight_test
from aeroid.models import catalog


def test_to_csv_file_with_a_bad_cell_names_its_file_line(tmp_path):
    # to_csv writes '# units: {...}' on line 1 and the header on line 2; the nan is on
    # line 11, which the message used to call row 10
    path = tmp_path / "f5.csv"
    catalog.short_period_flight(seed=1).to_csv(path)
    lines = path.read_text().splitlines()
    assert lines[0].startswith("# units:")
    cells = lines[10].split(",")
    cells[2] = "nan"
    lines[10] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    column = lines[1].split(",")[2]
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    assert f"f5.csv: row 11, column '{column}': non-finite value 'nan'" in str(err.value)


@pytest.mark.parametrize(
    ("cell", "fragment"),
    [
        ("", "row 7, column 'a': blank cell"),
        ("x", "row 7, column 'a': non-numeric ('x') cell"),
        ("inf", "row 7, column 'a': non-finite value 'inf'"),
        ("2,5", "row 7 has 3 cells, header has 2"),
        ("\xff", "row 7: byte"),
    ],
)
def test_row_is_the_file_line_past_comments_and_blank_lines(tmp_path, cell, fragment):
    # line 1 comment, 2 blank, 3 header, 4 data, 5 comment, 6 blank, 7 the bad cell
    path = tmp_path / "notes.csv"
    text = f"# flight 7\n\ntime,a\n0,1\n# gear up\n\n0.1,{cell}\n0.2,3\n"
    path.write_bytes(text.encode("latin-1"))
    with pytest.raises(DataFormatError) as err:
        load_flight_test(path)
    assert fragment in str(err.value)


def test_wide_file_row_is_the_file_line(tmp_path):
    # past 1000 columns the bad cell is found by Python's csv reader instead of pyarrow
    n = 1001
    head = ",".join(["time", *(f"c{j}" for j in range(n))])
    rows = [",".join([str(0.1 * i), *("1" for _ in range(n))]) for i in range(3)]
    rows[2] = rows[2].rsplit(",", 1)[0] + ",n/a"
    path = tmp_path / "wide.csv"
    path.write_text("# units: {}\n" + head + "\n" + rows[0] + "\n\n" + "\n".join(rows[1:]) + "\n")
    with pytest.raises(DataFormatError, match=rf"row 6, column 'c{n - 1}': non-numeric"):
        load_flight_test(path)


def test_units_comment_naming_a_missing_channel_warns(tmp_path):
    path = tmp_path / "f13.csv"
    path.write_text(
        '# units: {"alpha": "deg", "qq": "deg/s", "zz": "m"}\n'
        "time,alpha,q,elevator\n0,0,0,0\n0.02,0,0,0\n0.04,0,0,0\n"
    )
    with pytest.warns(UserWarning, match=r"f13\.csv: .*\['qq', 'zz'\].*no such column") as got:
        d = load_flight_test(path)
    assert len(got) == 1
    assert dict(d.units) == {"alpha": "deg"}


def test_units_comment_for_columns_left_unread_does_not_warn(tmp_path):
    # a column the file has but the caller did not ask for is no typo
    path = tmp_path / "ok.csv"
    aeroid.FlightData(
        [0.0, 0.1, 0.2], {"alpha": [0.0, 1.0, 2.0], "q": [0.0, 0.0, 0.0]}, {"q": "rad/s"}
    ).to_csv(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = load_flight_test(path, channels=["alpha"])
    assert d.names == ("alpha",)
