"""Model configuration: a frozen dataclass validated on construction."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from edge_depth.errors import ConfigError


@dataclass(frozen=True)
class ModelConfig:
    """widths: channels of the shared backbone at strides 2, 4, 8 (and 16 if downsample 8 uses
    it); feature_dim: correlation features; hidden_dim: ConvGRU state; downsample: 4 or 8;
    gru_levels: 1 or 2 (the second runs at half the GRU resolution); corr_levels and
    corr_radius: pyramid depth and lookup radius (pixels of each level); half_res_block: the
    backbone's residual block at 1/2 resolution (the encoder's most expensive layer; False
    goes from the stem straight to 1/4); refine: the half-resolution image-guided refinement
    with its confidence output (`edge.model.refine`): 0 none, 1 the images only (stage 4),
    2 the images and the LiDAR, with separate residual and confidence heads, 3 a choice
    among the convex upsampling's candidates scored by matching at 1/4 and by the LiDAR, 4 the
    1/4 stage (`edge.model.quarter`: local correlation at the backbone's 1/4 features, a
    distribution over offsets trained by cross-entropy, a residual per full-resolution
    pixel; downsample 8 only), 5 version 3 whose candidates are also scored by matching on
    the backbone's 1/4 features, 6 version 5 with a second scorer that sees all nine
    candidates over a 3×3 (then dilated) neighbourhood at 1/4, 7 version 5 whose choice
    also compares each full-resolution pixel's learned features with those of the 1/8 cells
    its candidates come from (never started), 8 version 7 written so that it starts, 9
    version 8 with a second, wider pixel side (from a version 8 checkpoint it starts as
    exactly version 8), 10 no image-guided stage: the convex upsampling with a confidence head
    at 1/8 on the last hidden state, its logit upsampled by the same convex weights (the
    full-resolution matching, `edge.runtime.edge_match`, does the edges' work);
    aux_offsets: while training only, the 1/4 stage's matching (its offsets head on the
    backbone's 1/4 features) as an auxiliary loss — not exported, no cost at inference; for
    any refine but 4 (which has the head itself), with downsample 8; refine_scale: the
    resolution versions 3 and 5-9 score their candidates at, 1/4 (shipped) or 1/2;
    motion_dim: the motion encoder's output (its correlation branch as wide), an input of the
    GRU's gates; head_dim: the hidden width of the Δd and upsampling-mask heads (the two
    last: knobs of a lighter update block, `experiments/prune.py`)."""

    widths: tuple[int, ...] = (16, 32, 48)
    feature_dim: int = 64
    context_dim: int = 48
    hidden_dim: int = 64
    downsample: int = 8
    gru_levels: int = 1
    corr_levels: int = 4
    corr_radius: int = 4
    gru_iters: int = 4
    cspn_steps: int = 4
    use_cspn: bool = True
    use_sparse: bool = True
    half_res_block: bool = True
    refine: int = 0
    aux_offsets: bool = False
    refine_scale: int = 4
    motion_dim: int = 64
    head_dim: int = 64

    def __post_init__(self) -> None:
        if isinstance(self.refine, bool):  # configs before versions: True was version 1
            object.__setattr__(self, "refine", int(self.refine))
        if self.refine not in range(11):
            raise ConfigError("refine", "0 to 10", self.refine)
        if self.refine_scale not in (2, 4):
            raise ConfigError("refine_scale", "2 or 4", self.refine_scale)
        if self.downsample not in (4, 8):
            raise ConfigError("downsample", "4 or 8", self.downsample)
        if self.aux_offsets and (self.refine == 4 or self.downsample != 8):
            raise ConfigError("aux_offsets", "a refine other than 4 and downsample 8 (version "
                              "4 has the offsets head itself)", (self.refine, self.downsample))
        if len(self.widths) != 3 or min(self.widths) < 1:
            raise ConfigError("widths", "three positive channel counts", self.widths)
        if self.gru_levels not in (1, 2):
            raise ConfigError("gru_levels", "1 or 2", self.gru_levels)
        for key in ("feature_dim", "context_dim", "hidden_dim", "corr_levels", "gru_iters",
                    "motion_dim", "head_dim"):
            if getattr(self, key) < 1:
                raise ConfigError(key, ">= 1", getattr(self, key))
        if self.corr_radius < 1 or self.cspn_steps < 0:
            raise ConfigError("corr_radius/cspn_steps", ">= 1 / >= 0",
                              (self.corr_radius, self.cspn_steps))

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> ModelConfig:
        data = dict(data)
        if "widths" in data:
            data["widths"] = tuple(data["widths"])
        return cls(**data)
