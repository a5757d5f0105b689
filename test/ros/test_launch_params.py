"""Which folder a relative calibration path resolves in when ``ros2 launch`` adds a params
file of its own (``use_sim_time:=true``) after the user's."""

from __future__ import annotations

from pathlib import Path

from strain_comp.ros.params import read_params


def test_a_params_file_without_a_calibration_does_not_move_the_base(tmp_path: Path) -> None:
    mine, launch = tmp_path / "robot", tmp_path / "tmp"
    mine.mkdir()
    launch.mkdir()
    (mine / "params.yaml").write_text("/**/compensator:\n  ros__parameters:\n"
                                      "    sensors: [s1]\n    s1: {calibration: cubic.yaml}\n")
    (launch / "launch_params.yaml").write_text("/**:\n  ros__parameters:\n"
                                               "    use_sim_time: true\n")
    files = [mine / "params.yaml", launch / "launch_params.yaml"]
    assert read_params(files)[1] == mine.resolve()
    # a later file that names a calibration moves it, as before
    (launch / "more.yaml").write_text("/**/compensator:\n  ros__parameters:\n"
                                      "    s1: {calibration: other.yaml}\n")
    assert read_params([*files, launch / "more.yaml"])[1] == launch.resolve()
    # a file with no calibration alone: its folder, as before
    assert read_params(files[1:])[1] == launch.resolve()
