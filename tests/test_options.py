"""One set of engine options: the dataclass, the robot file's [engine] keys, the engine flags
of replay and fleet and the configuration reference are the same set, derived from it."""

from __future__ import annotations

import argparse
from dataclasses import fields
from pathlib import Path

import pytest

from edge_depth.cli import build_parser
from edge_depth.config import RobotConfig, load_robot_config
from edge_depth.errors import ConfigError
from edge_depth.runtime.options import (
    EngineOptions,
    add_engine_arguments,
    options_from_args,
    reference_table,
)

ROOT = Path(__file__).resolve().parents[1]
NAMES = {f.name for f in fields(EngineOptions)}


def _flags(command: str) -> dict[str, str]:
    """dest -> the option string of each flag of `edge-depth COMMAND`."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return {a.dest: a.option_strings[0] for a in sub.choices[command]._actions
            if a.option_strings}


def test_the_options_the_config_keys_and_the_flags_are_one_set(tmp_path):
    assert {f.name: f.default_factory for f in fields(RobotConfig)}["engine"] is EngineOptions
    every_key = "\n".join(f"{f.name} = {f.default!r}".replace("'", '"').replace("False", "false")
                          .replace("True", "true") for f in fields(EngineOptions))
    path = tmp_path / "robot.toml"
    path.write_text("[engine]\n" + every_key + "\n")
    assert load_robot_config(path).engine == EngineOptions()  # every key read, none unknown
    path.write_text("[engine]\nnot_an_option = 1\n")
    with pytest.raises(ConfigError, match="engine.not_an_option"):
        load_robot_config(path)
    for command in ("replay", "fleet"):
        flags = _flags(command)
        assert NAMES <= set(flags), command
        assert {flags[n] for n in NAMES} == {"--" + n.replace("_", "-") for n in NAMES}


def test_flags_not_given_leave_the_defaults_and_given_ones_win():
    parser = argparse.ArgumentParser()
    add_engine_arguments(parser)
    assert options_from_args(parser.parse_args([])) == EngineOptions()
    args = parser.parse_args(["--threads", "1", "--refine", "off", "--no-lidar-select",
                              "--bf16", "off", "--edge-median", "bundle"])
    options = options_from_args(args, threads=3)
    assert (options.threads, options.refine, options.lidar_select, options.bf16_choice,
            options.edge_median) == (1, "off", False, False, "bundle")
    assert options_from_args(parser.parse_args([]), threads=3).threads == 3
    with pytest.raises(SystemExit):
        parser.parse_args(["--refine", "sgbm"])
    with pytest.raises(SystemExit):  # a removed option is no flag
        parser.parse_args(["--edge-match", "64"])


def test_a_bad_value_is_refused_naming_the_option():
    with pytest.raises(ConfigError, match="threads: expected 1–256"):
        EngineOptions(threads=0)
    with pytest.raises(ConfigError, match="edge_median"):
        EngineOptions(edge_median="5x5")


def test_the_configuration_reference_holds_the_table_the_options_make():
    text = (ROOT / "docs" / "configuration.md").read_text()
    assert reference_table() in text
    assert all(f"| `{name}` |" in reference_table() for name in NAMES)


@pytest.mark.parametrize("key", ["match_photometry", "edge_select", "edge_match",
                                 "edge_match_rows", "edge_matcher", "edge_match_far_px"])
def test_an_engine_option_the_band_made_redundant_is_refused_saying_why(tmp_path, key):
    cfg = tmp_path / "robot.toml"
    cfg.write_text(f"[engine]\n{key} = true\n")
    with pytest.raises(ConfigError, match=rf"robot.toml: engine.{key}: expected a current key "
                                          r"\(this one was removed: .*band refinement.*delete "
                                          rf"the key\), got '{key}'"):
        load_robot_config(cfg)
