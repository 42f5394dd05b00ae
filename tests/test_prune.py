"""`tools/prune.py`: a lighter update block cut from a trained checkpoint."""

from __future__ import annotations

import pytest
import torch

from edge_depth.errors import ConfigError
from edge_depth.model.config import ModelConfig
from edge_depth.model.network import SparseStereoNet
from edge_depth.tools.prune import main, prune_state

SMALL = dict(widths=(8, 8, 16), feature_dim=16, context_dim=8, hidden_dim=16, motion_dim=12,
             head_dim=8, corr_levels=2, corr_radius=2, refine=8)


def _inputs():
    gen = torch.Generator().manual_seed(1)
    img = torch.rand(1, 1, 64, 96, generator=gen) * 255
    valid = (torch.rand(1, 1, 64, 96, generator=gen) < 0.05).float()
    return img, torch.roll(img, -3, 3), valid * 3.0, valid


def test_the_knobs_size_the_update_block_and_are_checked():
    net = SparseStereoNet(ModelConfig(**SMALL))
    assert net.update.motion.corr.weight.shape[0] == 12
    assert net.update.motion.out.weight.shape[:2] == (11, 12 + 16)  # + the disparity: 12
    assert net.update.gru.convzr.weight.shape[:2] == (32, 16 + 12 + 8)
    assert net.update.delta[0].weight.shape[0] == net.update.mask[0].weight.shape[0] == 8
    for key in ("motion_dim", "head_dim"):
        with pytest.raises(ConfigError, match=key):
            ModelConfig(**{**SMALL, key: 0})


def test_pruning_to_the_same_sizes_is_the_same_network():
    torch.manual_seed(0)
    config = ModelConfig(**SMALL)
    net = SparseStereoNet(config).eval()
    state, same = prune_state(net.state_dict(), config, {})
    assert same == config
    copy = SparseStereoNet(same).eval()
    copy.load_state_dict(state)
    with torch.no_grad():
        torch.testing.assert_close(copy(*_inputs(), iters=2)[-1], net(*_inputs(), iters=2)[-1],
                                   atol=0, rtol=0)


def test_pruning_keeps_the_channels_the_next_layers_read_most():
    torch.manual_seed(0)
    config = ModelConfig(**SMALL)
    net = SparseStereoNet(config)
    state = net.state_dict()
    # hidden channels 0-5 and context channels 0-2 are nearly unread: they go first
    for name in ("update.gru.convzr.weight", "update.gru.convq.weight"):
        state[name][:, :6] *= 1e-3
        state[name][:, 16 + 12:16 + 12 + 3] *= 1e-3
    for name in ("update.delta.0.weight", "update.mask.0.weight"):
        state[name][:, :6] *= 1e-3
    pruned, light = prune_state(state, config, dict(hidden=10, context=5, motion=6, head=4,
                                                    feature=12))
    assert (light.hidden_dim, light.context_dim, light.motion_dim, light.head_dim,
            light.feature_dim) == (10, 5, 6, 4, 12)
    small = SparseStereoNet(light).eval()
    small.load_state_dict(pruned)  # strict: every shape is the pruned config's
    # the kept hidden channels are 6-15, in order: their gates' rows and input columns
    zr = state["update.gru.convzr.weight"]
    torch.testing.assert_close(pruned["update.gru.convq.weight"][:, :10],
                               state["update.gru.convq.weight"][6:16, 6:16])
    torch.testing.assert_close(pruned["update.gru.convzr.weight"][10:, :10], zr[16 + 6:, 6:16])
    # the context: channels 3-7 of the encoder's context head (after the 16 hidden rows)
    torch.testing.assert_close(pruned["encoders.context_head.weight"][10:],
                               state["encoders.context_head.weight"][16 + 3:])
    # the motion features' last channel, the disparity itself, is always kept last
    torch.testing.assert_close(pruned["update.gru.convq.weight"][:, 10 + 5],
                               state["update.gru.convq.weight"][6:16, 16 + 11])
    with torch.no_grad():
        out = small(*_inputs(), iters=2)[-1]
    assert out.shape == (1, 1, 64, 96) and torch.isfinite(out).all()


def test_the_command_writes_a_checkpoint_train_can_start_from(tmp_path, capsys):
    torch.manual_seed(0)
    config = ModelConfig(**SMALL)
    src = tmp_path / "full.pt"
    torch.save(dict(model=SparseStereoNet(config).state_dict(), config=config.to_dict(),
                    step=7), src)
    assert main([str(src), "--out", str(tmp_path / "light.pt"), "--hidden", "12"]) == 0
    assert "hidden_dim 16 -> 12" in capsys.readouterr().out
    ckpt = torch.load(tmp_path / "light.pt", weights_only=False)
    assert ckpt["config"]["hidden_dim"] == 12 and ckpt["step"] == 7
    assert ckpt["pruned"] == dict(hidden=12, context=8, motion=12, head=8, feature=16)
    SparseStereoNet(ModelConfig.from_dict(ckpt["config"])).load_state_dict(ckpt["model"])
    with pytest.raises(SystemExit, match="cannot keep 20 of 16"):
        main([str(src), "--out", str(tmp_path / "x.pt"), "--hidden", "20"])
    with pytest.raises(SystemExit):
        main([str(src), "--out", str(tmp_path / "x.pt"), "--head", "0"])
