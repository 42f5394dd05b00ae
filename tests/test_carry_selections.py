import json

import pytest

from edge_depth.tools.carry_selections import carry, main


def bundle(tmp_path, name, **meta):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "model.json").write_text(json.dumps(dict(format=1, step=name, **meta)))
    return folder


def test_carry_copies_the_lidar_selection_and_keeps_the_rest(tmp_path):
    old = bundle(tmp_path, "old", lidar_select={"w": [1, 2]}, edge_select={"w": [3]})
    new = bundle(tmp_path, "new", lidar_select={"w": [9]})
    assert carry(old, new) == ["lidar_select"]  # an old edge selection is no stage now
    meta = json.loads((new / "model.json").read_text())
    assert meta == dict(format=1, step="new", lidar_select={"w": [1, 2]})
    only_lidar = bundle(tmp_path, "lidar", lidar_select={"w": [5]})
    assert carry(only_lidar / "model.json", new) == ["lidar_select"]  # a file works too
    assert json.loads((new / "model.json").read_text())["lidar_select"] == {"w": [5]}


def test_carry_refuses_a_source_without_selections_in_one_line(tmp_path, capsys):
    bare, new = bundle(tmp_path, "bare"), bundle(tmp_path, "new")
    with pytest.raises(ValueError, match="no lidar_select to carry"):
        carry(bare, new)
    (tmp_path / "weights.pt").write_bytes(b"\x80\x02binary")
    assert main([str(tmp_path / "weights.pt"), str(new)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a bundle's model.json" in err[0]
    assert json.loads((new / "model.json").read_text()) == dict(format=1, step="new")
