"""Model configuration: a frozen dataclass validated on construction."""

from __future__ import annotations

from dataclasses import asdict, dataclass

from edge_depth.errors import ConfigError

REFINE_VERSIONS = (0, 10)
# configuration keys of removed training stages, and the value that means "not used"
REMOVED_KEYS = {"aux_offsets": False, "refine_scale": 4}


@dataclass(frozen=True)
class ModelConfig:
    """widths: channels of the shared backbone at strides 2, 4, 8 (and 16 if downsample 8 uses
    it); feature_dim: correlation features; hidden_dim: ConvGRU state; downsample: 4 or 8;
    gru_levels: 1 or 2 (the second runs at half the GRU resolution); corr_levels and
    corr_radius: pyramid depth and lookup radius (pixels of each level); half_res_block: the
    backbone's residual block at 1/2 resolution (the encoder's most expensive layer; False
    goes from the stem straight to 1/4); refine: 0 no confidence, 10 the confidence head
    (`edge.model.refine`: on the last hidden state at 1/8, upsampled by the convex weights;
    the engine's full-resolution matching does the edges' work). Versions 1-9, image-guided
    refinements at 1/2 and 1/4, were removed (tag model-versions-archive);
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
    motion_dim: int = 64
    head_dim: int = 64

    def __post_init__(self) -> None:
        if self.refine not in REFINE_VERSIONS:
            raise ConfigError("refine", "0 (no confidence) or 10 (the confidence head; "
                              "versions 1-9 are in the tag model-versions-archive)",
                              self.refine)
        if self.downsample not in (4, 8):
            raise ConfigError("downsample", "4 or 8", self.downsample)
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
        """A checkpoint's config; the keys of removed stages are dropped when they are at
        their neutral values (an older checkpoint of version 10 or 0 still loads)."""
        data = dict(data)
        for key, neutral in REMOVED_KEYS.items():
            if data.get(key, neutral) != neutral:
                raise ConfigError(key, f"{neutral!r} (that stage was removed; tag "
                                  "model-versions-archive)", data[key])
            data.pop(key, None)
        if "widths" in data:
            data["widths"] = tuple(data["widths"])
        return cls(**data)
