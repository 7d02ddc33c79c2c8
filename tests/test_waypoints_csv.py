"""A waypoint CSV file read by its columns' names against the rig's joints (``pneumactl
waypoints``, ``evaluation --reference FILE``): never by their position, and a name that is not
a joint's, a joint left out or a column given twice is refused, saying what the header must be."""
from __future__ import annotations

import pytest

from daemon.client.client import read_waypoints

ARM = [("bottom", "deg"), ("middle", "deg")]


def csv_file(tmp_path, text: str):
    path = tmp_path / "points.csv"
    path.write_text(text)
    return path


def test_joint_columns_are_read_by_name_in_any_order(tmp_path):
    path = csv_file(tmp_path, "# a joint path\nduration_s,middle_deg,bottom_deg\n0,-100,10\n4,-95,20\n\n3,-100,15\n")
    assert read_waypoints(path, ARM) == {"positions": [[10, -100], [20, -95], [15, -100]], "durations_s": [4, 3]}


def test_a_linear_joint_is_given_in_mm(tmp_path):
    path = csv_file(tmp_path, "duration_s,axis_mm\n0,50\n2,150\n")
    assert read_waypoints(path, [("axis", "mm")]) == {"positions": [[50], [150]], "durations_s": [2]}


def test_cartesian_points_need_no_joints(tmp_path):
    path = csv_file(tmp_path, "duration_s,x_mm,y_mm\n0,70,135\n5,20,150\n")
    assert read_waypoints(path, ARM) == {"xy_mm": [[70, 135], [20, 150]], "durations_s": [5]}


@pytest.mark.parametrize("header, words", [
    ("foo_deg,bar_deg", "columns foo_deg,bar_deg not this rig's joints"),
    ("bottom_mm,middle_deg", "column bottom_mm not this rig's joints"),
    ("bottom_deg", "column middle_deg missing"),
    ("bottom_deg,middle_deg,bottom_deg", "column bottom_deg given twice"),
])
def test_unknown_missing_or_repeated_columns_are_refused_saying_the_header_wanted(tmp_path, header, words):
    values = ",".join(["1"] * (header.count(",") + 1))
    path = csv_file(tmp_path, f"duration_s,{header}\n0,{values}\n1,{values}\n")
    with pytest.raises(ValueError, match=words) as refused:
        read_waypoints(path, ARM)
    assert "duration_s,bottom_deg,middle_deg (any order)" in str(refused.value)


def test_a_row_shorter_than_the_header_is_refused(tmp_path):
    path = csv_file(tmp_path, "duration_s,bottom_deg,middle_deg\n0,1,2\n1,2\n")
    with pytest.raises(ValueError, match="every row needs 3 values"):
        read_waypoints(path, ARM)


def test_a_header_without_duration_s_is_refused(tmp_path):
    path = csv_file(tmp_path, "t,a,b\n0,1,2\n1,2,3\n")
    with pytest.raises(ValueError, match="header starting with duration_s"):
        read_waypoints(path, ARM)
