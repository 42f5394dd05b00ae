"""`edge-depth train | evaluate | export | quantize | bench | ...`: the tools as subcommands."""

from __future__ import annotations

import sys

import pytest

from edge_depth.cli import TOOL_COMMANDS, main


def test_a_tool_parses_its_own_arguments_under_its_subcommand_name(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["bench", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: edge-depth bench") and "--runtimes" in out
    with pytest.raises(SystemExit) as exit_info:  # a usage error: 2, as for edge-depth's own
        main(["evaluate", "/nonexistent-folder", "--methods", "sgbm"])
    assert exit_info.value.code == 2
    assert "edge-depth evaluate: error: no scene folders" in capsys.readouterr().err


def test_without_torch_a_training_tool_names_the_extra_in_one_line(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch", None)  # import torch now fails
    for module in ("edge_depth.tools.train", "edge_depth.tools.export"):
        monkeypatch.delitem(sys.modules, module, raising=False)
    assert main(["train", "--steps", "1", "--out", "/tmp/never"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "edge-depth[train]" in err and "needs torch" in err
    assert "whl/cpu" in err


def test_every_tool_command_has_a_main():
    import importlib

    for name, (module, _) in TOOL_COMMANDS.items():
        if name in ("train", "export"):
            continue  # torch: imported by the tests that train
        assert callable(importlib.import_module(f"edge_depth.{module}").main), name


def test_without_depthai_the_oak_names_its_extra_in_one_line(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "depthai", None)  # import depthai now fails
    config = tmp_path / "robot.toml"
    config.write_text('[camera]\nsource = "oak"\n[lidar]\nmodel = "none"\n')
    assert main(["run", "--config", str(config), "--out", str(tmp_path / "o.mcap")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "depthai" in err and "edge-depth[oak]" in err
    assert not (tmp_path / "o.mcap").exists()


def test_without_rclpy_the_ros2_node_names_its_extra_in_one_line(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "rclpy", None)  # import rclpy now fails
    assert main(["ros2", "--calib", "/nonexistent.toml"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "rclpy" in err and "pip install 'edge-depth[ros2]'" in err


def test_a_ros_domain_id_out_of_range_is_one_line(monkeypatch, capsys):
    monkeypatch.setenv("ROS_DOMAIN_ID", "500")
    assert main(["ros2-play", "/nonexistent.mcap"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == ("edge-depth ros2-play: error: ROS_DOMAIN_ID: expected an integer 0-232 (the "
                   "environment variable), got '500'")


def test_every_subcommands_help_renders(capsys):
    # an option's doc with a bare "%" broke argparse's help (its own % formatting)
    from edge_depth.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if a.choices and "replay" in a.choices)
    for name, command in sub.choices.items():
        if name in TOOL_COMMANDS:
            continue  # the tools parse their own arguments (the test above)
        text = command.format_help()
        assert text.startswith(f"usage: edge-depth {name}"), name
    assert "1-21 % at 0.75-1.5 px" in sub.choices["replay"].format_help()  # a % escaped
