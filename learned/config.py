"""Configs of the depth + motion + intrinsics networks and their training, with named presets."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from learned.travel import TRAVEL_SIZE
from learned.view import VIEW_SIZE


@dataclass(frozen=True)
class DepthConfig:
    """Network sizes, losses and training schedule of the unsupervised depth learner."""

    preset: str = "fast"
    """Name of the preset this config came from."""
    height: int = 128
    """Network input height (pixels)."""
    width: int = 160
    """Network input width (pixels)."""
    encoder_channels: tuple[int, ...] = (16, 24, 32, 64, 96)
    """Depth encoder: stem channels, then the four residual stages."""
    encoder_blocks: tuple[int, ...] = (1, 1, 1, 1)
    """Residual blocks per encoder stage."""
    decoder_channels: tuple[int, ...] = (16, 16, 24, 32, 48)
    """Depth decoder channels at strides 1, 2, 4, 8, 16."""
    motion_channels: tuple[int, ...] = (16, 24, 32, 64, 96)
    """Motion encoder: stem channels, then the four residual stages."""
    motion_blocks: tuple[int, ...] = (1, 1, 1, 1)
    """Residual blocks per motion encoder stage."""
    motion_net: str = "stacked"
    """Motion network: "stacked" (the two frames stacked into one encoder, as Gordon et al.)
    or "correlation" (one encoder shared by both frames, the motion encoder's stem and first
    stage, the correlation of their features over shifts, then convolutions of 64, 96 and 128
    channels in every preset; learned.nets.PairCorrelation)."""
    motion_reach: int = 4
    """Correlation motion network: largest shift compared, in feature pixels (4 image pixels
    each) either way."""
    min_depth: float = 0.1
    """Smallest depth the network can output (its scale is arbitrary)."""
    max_depth: float = 100.0
    """Largest depth the network can output."""
    pair_gap_s: float = 0.3
    """Time between the target frame and each source frame."""
    input_fps: float = 0.0
    """Frame rate of training videos and image folders whose own is missing or wrong (0:
    theirs; image folders 30); refused with simulated procedures, which have their own."""
    batch_size: int = 8
    """Triplets per step."""
    learning_rate: float = 5e-4
    """Adam learning rate."""
    lr_drop_step: int = 0
    """From this step on the learning rate is multiplied by lr_drop_factor (0: never)."""
    lr_drop_factor: float = 0.1
    """Factor of the learning-rate drop."""
    grad_clip: float = 10.0
    """Gradient norm clip."""
    mirror: bool = False
    """Mirror each training triplet left-right and up-down, each with chance 1/2 (a mirrored
    video is a video of a mirrored colon; the --maps batches stay as they are)."""
    steps: int = 6000
    """Training steps."""
    w_ssim: float = 0.85
    """Weight of (1 - SSIM) / 2 in the photometric error."""
    ssim_window: int = 3
    """SSIM window (pixels)."""
    w_l1: float = 0.15
    """Weight of L1 in the photometric error."""
    photo_blur: float = 0.0
    """Gaussian blur (standard deviation, pixels at the network's size) of the target and the
    sources before the photometric error compares them, 0 = off: the sensor noise of
    low-contrast frames no longer fills the error (highlights are still found on the sharp
    images)."""
    photo_blur_on: str = "all"
    """Which view synthesis photo_blur blurs: "all", or "maps" (only the --maps batches', whose
    motion and K come from the maps, so that the motion network learns from sharp images)."""
    coarse_levels: int = 0
    """Also compare target and source at 1/2, 1/4, ... resolution (block means), averaged with
    the full-resolution error: wider-reaching gradients, less sensor noise on weak texture."""
    w_smooth: float = 1e-3
    """Edge-aware smoothness of mean-normalised disparity."""
    w_depth_consistency: float = 1e-2
    """Occlusion-aware depth consistency between target and sources."""
    w_flow: float = 0.0
    """Rigid flow of the predicted motion and K (depth held fixed) against OpenCV's DIS optical
    flow (learned.flow); 0: off, as measured it does not help (docs/depth.md)."""
    flow_scale_px: float = 2.0
    """Scale of the Cauchy penalty of the flow term (pixels)."""
    w_chain: float = 0.0
    """L1 (radians per axis) between the rotation target -> previous frame and the composition
    of the motion net's own estimates over the chain_steps steps between them (no gradient
    through the chain); 0: off."""
    chain_steps: int = 9
    """Steps of the chain term: frames previous + round(j * gap / chain_steps), j = 0 ... . The
    steps are single frames when chain_steps equals the pair gap in frames (9 at 30 fps); a
    gap shorter than chain_steps is refused."""
    chain_teacher: str = "self"
    """Whose small-step estimates the chain term composes: "self" (the model being trained) or
    "init" (the `init` model, frozen, so that they cannot drift with training)."""
    w_rotation_cycle: float = 1e-3
    """Forward and backward rotations compose to the identity."""
    w_translation_cycle: float = 1e-2
    """Forward and backward translations cancel."""
    mask_out_of_view: bool = True
    """Ignore pixels that project outside the source (Gordon et al.). Off, they are compared
    with the border-padded source as in monodepth2."""
    automask: bool = True
    """Ignore pixels that the un-warped source explains better (static scenes)."""
    brightness_match: bool = True
    """Match each warped source's per-channel mean and std to the target's."""
    specular_mask: bool = True
    """Ignore near-white specular highlights."""
    inverse_square: bool = False
    """Relight the warped source for the light at the camera: its intensity times (source ray
    length / target ray length)^(2 / display_gamma), with gradients to depth and motion, so
    that the light's falloff is a depth cue where parallax is weak."""
    w_shading: float = 0.0
    """Inverse-square shading prior on the target's depth and K (learned.shading): the light at
    the camera as a cue where parallax is weak; 0: off."""
    shading_steers: str = "depth"
    """What the shading prior's gradient reaches: "depth", "intrinsics" (the depth held fixed
    in it, so it trains K's head and the motion encoder it shares with the pose) or "both"."""
    display_gamma: float = 2.2
    """Gamma of the video's encoding (the inverse-square law holds for linear intensity)."""
    w_zoom: float = 0.0
    """Zoom consistency of the intrinsics head (learned.zoom): the K read from a random crop
    of a pair, enlarged to the full size, must be the K read from the whole pair carried
    through the zoom; 0: off."""
    zoom_max: float = 1.5
    """Largest zoom of the crops of the zoom consistency and of map_zoom (their size 1/s of
    the frame's, s log-uniform in [1, zoom_max])."""
    zoom_updates_bn: bool = True
    """Whether the batches of the zoom consistency and of map_zoom (crops, and whole frames
    blurred to their detail) update the motion network's batch-norm running statistics,
    which inference uses. False leaves them to the ordinary frames and the map batches
    (docs/depth.md, "Batch norm's statistics recomputed": it did not remove the shift of the
    head's focal length that those statistics cause; recomputing them did)."""
    motion_noise: float = 0.0
    """Training only: Gaussian noise added to each frame the motion network reads (not to the
    images the loss compares; not clipped), its standard deviation (0..1 scale) drawn per pair
    uniformly from [0, motion_noise], so that the head is less able to read a style's sensor
    noise as its focal length (docs/depth.md, section "Cameras shared by the styles"); 0:
    off. It reaches the zoom and map crop batches too, after their enlargement. The running
    batch-norm statistics are then gathered on noisy frames and inference reads clean ones:
    recompute them (bn_recompute_batches) before reading the head."""
    maps: str = ""
    """Folder of structure-from-motion maps of the training inputs (`c2d2 sfm-maps`); each
    step then also draws a batch of triplets from their agreeing stretches
    (learned.map_triplets); empty: none."""
    w_map: float = 0.0
    """View synthesis of the map batch with the maps' motion and K (trains the depth)."""
    w_map_motion: float = 0.0
    """Distance of the motion network's rotation, translation direction and focal length
    from the maps' on the map batch (trains the motion network and its intrinsics head)."""
    map_zoom: bool = False
    """The motion network's map term (w_map_motion) reads each map triplet cut to a random box
    (learned.zoom: its size 1/s of the frame's, s log-uniform in [1, zoom_max]) and enlarged,
    against the map's K carried through the zoom, and the whole triplet at the crop's detail
    against the map's K (learned.map_triplets.zoomed_map_targets): a crop of a mapped frame is
    a frame of a camera with s times the focal length and the same motion, so the head is
    pulled towards more focal lengths than the training cameras'. Its batch updates batch
    norm's running statistics as zoom_updates_bn says."""
    map_min_points: int = 20
    """Map points a target must see to be drawn (they set the maps' unit)."""
    bn_recompute_batches: int = 0
    """At the end of the run, the motion network's batch-norm running statistics (which
    inference uses) are reset and recomputed as a plain average over this many batches of
    ordinary triplets (learned.train.recompute_motion_statistics), in place of training's
    exponential average, which weighs the last few batches of every kind (map batches and
    zoom crops too); 0: kept as training left them."""
    depth_views: int = 1
    """Inference only: the depth read from the frame and its mirror images (1: the frame
    alone; 2: and left-right; 4: and up-down, and both), each mirrored back, averaged in log
    depth (DepthModel.predict_depth). Training and its validation never read it; a finished
    run asked for another value (train-depth --set depth_views=N, N > 1) writes its model
    again with it."""
    seed: int = 0
    """Random seed (initialisation and sampling)."""
    init: str = ""
    """Depth model whose weights a new run starts from (fine-tuning); empty: random."""

    def __post_init__(self) -> None:
        block = 2**self.coarse_levels
        if self.coarse_levels < 0 or self.height % block or self.width % block \
                or min(self.height, self.width) < 8 * block:
            raise ValueError(f"coarse_levels={self.coarse_levels} needs a size divisible by "
                             f"{block} and at least {8 * block} pixels, got "
                             f"{self.height}x{self.width}")
        if self.steps < 1 or self.batch_size < 1 or self.seed < 0:
            raise ValueError(f"steps and batch_size must be >= 1 and seed >= 0, got "
                             f"{self.steps}, {self.batch_size} and {self.seed}")
        if self.w_chain < 0 or self.chain_steps < 1:
            raise ValueError(f"w_chain must be >= 0 and chain_steps >= 1, got {self.w_chain} "
                             f"and {self.chain_steps}")
        if self.chain_teacher not in ("self", "init") or (self.chain_teacher == "init"
                                                          and not self.init):
            raise ValueError(f"chain_teacher must be 'self' or 'init' (with an init model), "
                             f"got {self.chain_teacher!r}")
        if not self.w_shading >= 0:
            raise ValueError(f"w_shading must be >= 0, got {self.w_shading}")
        if self.shading_steers not in ("depth", "intrinsics", "both"):
            raise ValueError(f"shading_steers must be 'depth', 'intrinsics' or 'both', got "
                             f"{self.shading_steers!r}")
        if not (self.w_map >= 0 and self.w_map_motion >= 0 and self.map_min_points >= 1) or \
                bool(self.maps) != bool(self.w_map or self.w_map_motion):
            raise ValueError(f"maps (train-depth --maps) need w_map or w_map_motion > 0 "
                             f"(e.g. --set w_map=1), weights >= 0 and map_min_points >= 1, and "
                             f"those weights need maps; got "
                             f"maps={self.maps!r}, w_map={self.w_map}, w_map_motion="
                             f"{self.w_map_motion}, map_min_points={self.map_min_points}")
        if not self.photo_blur >= 0:
            raise ValueError(f"photo_blur must be >= 0 (pixels), got {self.photo_blur}")
        if self.photo_blur_on not in ("all", "maps") or (self.photo_blur_on == "maps"
                                                         and not self.w_map):
            raise ValueError(f"photo_blur_on must be 'all' or 'maps', and 'maps' needs the "
                             f"maps' view term (w_map > 0); got {self.photo_blur_on!r} with "
                             f"w_map={self.w_map}")
        if self.depth_views not in (1, 2, 4):
            raise ValueError(f"depth_views must be 1, 2 or 4, got {self.depth_views}")
        if self.bn_recompute_batches < 0:
            raise ValueError(f"bn_recompute_batches must be >= 0, got "
                             f"{self.bn_recompute_batches}")
        if self.map_zoom and not self.w_map_motion:
            raise ValueError(f"map_zoom needs w_map_motion > 0 (it zooms the motion "
                             f"network's map term), got w_map_motion={self.w_map_motion}")
        if not (self.w_zoom >= 0 and self.zoom_max > 1):
            raise ValueError(f"w_zoom must be >= 0 and zoom_max > 1, got {self.w_zoom} and "
                             f"{self.zoom_max}")
        if self.motion_net not in ("stacked", "correlation") or self.motion_reach < 1:
            raise ValueError(f"motion_net must be 'stacked' or 'correlation' and motion_reach "
                             f">= 1, got {self.motion_net!r} and {self.motion_reach}")
        if not self.motion_noise >= 0:
            raise ValueError(f"motion_noise must be >= 0, got {self.motion_noise}")
        if not self.display_gamma > 0:
            raise ValueError(f"display_gamma must be positive, got {self.display_gamma}")
        if not self.input_fps >= 0:
            raise ValueError(f"input_fps must be positive (0: the inputs' own), got "
                             f"{self.input_fps}")

    def lr_at(self, step: int) -> float:
        """Learning rate of training step `step` (counted from 0)."""
        dropped = 0 < self.lr_drop_step <= step
        return self.learning_rate * (self.lr_drop_factor if dropped else 1.0)

    def ordinary_view(self) -> DepthConfig:
        """The config of the ordinary batches' view synthesis: without photo_blur where
        photo_blur_on keeps it to the maps' batches."""
        return replace(self, photo_blur=0.0) if self.photo_blur_on == "maps" else self

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> DepthConfig:
        known = {f.name for f in fields(cls)}
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k in known}
        return cls(**values)


DEPTH_PRESETS: dict[str, DepthConfig] = {
    "fast": DepthConfig(),
    "paper": DepthConfig(
        preset="paper", height=320, width=384,
        encoder_channels=(64, 64, 128, 256, 512), encoder_blocks=(2, 2, 2, 2),
        decoder_channels=(16, 32, 64, 128, 256),
        motion_channels=(64, 64, 128, 256, 512), motion_blocks=(2, 2, 2, 2),
        batch_size=4, learning_rate=2e-4, steps=200_000,
    ),
}
"""`fast` is sized for a 2-core CPU; `paper` is ResNet-18 at 320x384 as in the paper."""


def depth_config(preset: str, **overrides) -> DepthConfig:
    if preset not in DEPTH_PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(DEPTH_PRESETS)}")
    return replace(DEPTH_PRESETS[preset], **{k: v for k, v in overrides.items() if v is not None})


def parse_overrides(items: list[str], defaults=DEPTH_PRESETS["fast"]) -> dict:
    """{'pair_gap_s': 0.6} from ['pair_gap_s=0.6'], each value parsed as the type of its field
    in defaults (a config dataclass); a tuple of integers is written 32,48,64 and keeps the
    default's length."""
    types = {f.name: type(getattr(defaults, f.name)) for f in fields(defaults)}
    out = {}
    for item in items:
        key, sep, text = item.partition("=")
        if not sep or key not in types or key == "preset":
            names = ", ".join(k for k in types if k != "preset")
            raise ValueError(f"--set {item!r}: expected FIELD=VALUE with one of {names}")
        kind = types[key]
        if kind is tuple:
            default = getattr(defaults, key)
            try:
                value = tuple(int(v) for v in text.split(","))
            except ValueError as err:
                raise ValueError(f"--set {item!r}: {key} takes integers separated by commas"
                                 ) from err
            if len(value) != len(default):
                raise ValueError(f"--set {item!r}: {key} takes {len(default)} values, like "
                                 f"{','.join(map(str, default))}")
            out[key] = value
        elif kind is bool:
            if text.lower() not in ("true", "false"):
                raise ValueError(f"--set {item!r}: {key} takes true or false")
            out[key] = text.lower() == "true"
        else:
            try:
                out[key] = kind(text)
            except ValueError as err:
                raise ValueError(f"--set {item!r}: {key} takes a {kind.__name__}") from err
    return out


@dataclass(frozen=True)
class CoverageConfig:
    """The two-stage coverage networks (paper section 4.2) and their training."""

    preset: str = "fast"
    """Name of the preset this config came from."""
    height: int = 64
    """Per-frame network input height (depth images are resized to it)."""
    width: int = 80
    """Per-frame network input width."""
    frame_channels: tuple[int, ...] = (16, 32, 64, 96, 128)
    """Per-frame encoder: stem channels, then the four residual stages; the last is the
    feature size F."""
    frame_blocks: tuple[int, ...] = (1, 1, 1, 1)
    """Residual blocks per per-frame encoder stage."""
    bottleneck: bool = False
    """Bottleneck residual blocks (ResNet-50) instead of basic ones."""
    input_depth: str = "predicted"
    """Per-frame input: 'predicted' (the depth network's output on the RGB, as at inference)
    or 'true' (the simulator's depth, an ablation)."""
    median_normalise: bool = True
    """Divide each depth map by its median (the rule for depth of unknown scale); False feeds
    log depth as is: centimetres for true depth, the depth network's own units for predicted
    depth, which carry part of the true scale across videos (docs/coverage.md, "The depth
    network's own scale as an input")."""
    travel_gap: int = 8
    """Frames (at frame_rate) between the motion network's pair that gives each frame's
    direction of travel, an input of the per-frame network besides the depth
    (learned.travel); 0: depth only, as in the paper."""
    travel_hops: int = 8
    """Also the travel over this many travel gaps, chained from the motion network's pairs
    (learned.travel.chain_relative), as four more cues: a longer baseline (8 x 8 frames,
    2.1 s at 30 fps) than the travel gap's (0: off)."""
    field_of_view: str = "none"
    """Camera input of the per-frame network besides the depth: 'predicted' (the median
    intrinsics of the motion network's consecutive pairs, as `c2d2 run` has them), 'true' (the
    simulator's camera: an ablation, or with view_hidden, networks that `c2d2 run
    --self-calibrate` gives the self-calibrated one) or 'none' (learned.view)."""
    view_hidden: float = 0.0
    """Training with a field of view: the chance that it is hidden, given as unknown (a third
    value, 'known', 0: learned.view.hidden_view), for each stage-1 training frame and for each
    procedure whose stage-2 features are computed; so that one network takes videos whose
    camera is known and videos whose camera is not (0: always given, two values)."""
    depth_scale: bool = False
    """Give the per-frame network each frame's depth scale against its video's,
    log(median depth / the video's median of the frames' median depths), as one more cue
    (learned.coverage_nets.relative_scale)."""
    frame_rate: float = 30.0
    """Frame rate of the training videos: a segment of segment_frames lasts
    segment_frames / frame_rate seconds; other videos' travel gap is scaled by time."""
    segment_frames: int = 300
    """Frames per segment (T)."""
    segment_stride: int = 30
    """Start-to-start frames of the overlapping training windows."""
    calibrate: bool = False
    """Map the final model's segment output through a monotone table fitted on the
    cross-validation's held-out windows (learned.calibration). Off as shipped: it helped the
    cross-validation and hurt 24 held-out procedures of another length (docs/coverage.md);
    cv_metrics.json reports the cross-fitted calibrated figures either way."""
    segment_channels: tuple[int, ...] = (8, 16, 16, 16, 16, 16)
    """Output channels of the per-segment network's six 1-D convolutions."""
    segment_kernels: tuple[int, ...] = (1, 5, 5, 5, 5, 5)
    """Their kernel sizes (frames)."""
    segment_strides: tuple[int, ...] = (1, 2, 2, 2, 2, 2)
    """Their temporal strides."""
    frame_epochs: int = 4
    """Stage 1 passes over the training frames."""
    frame_batch: int = 64
    """Stage 1 batch size (frames)."""
    frame_lr: float = 1e-3
    """Stage 1 Adam learning rate (cosine-annealed)."""
    segment_epochs: int = 150
    """Stage 2 passes over the training windows."""
    segment_batch: int = 32
    """Stage 2 batch size (windows)."""
    segment_lr: float = 2e-3
    """Stage 2 Adam learning rate (cosine-annealed)."""
    frame_loss: str = "l2"
    """Stage 1 loss on the per-frame coverages: 'l2' (the paper) or 'l1' (the fast preset),
    whose minimiser is the conditional median, the estimate of least mean absolute error."""
    segment_loss: str = "l2"
    """Stage 2 loss on the window coverages: 'l2' (the paper) or 'l1'."""
    frame_precision: str = "float32"
    """Stage 1 arithmetic: 'float32', or 'bfloat16' (autocast: the per-frame network's
    passes in bfloat16, its weights, optimiser and loss in float32). Prediction is float32
    either way."""
    weight_decay: float = 1e-4
    """AdamW weight decay of both stages."""
    depth_power: float = 0.0
    """Stage 1 augmentation: each training depth map is raised to a random power exp(u), u
    uniform in ±depth_power (0: off), as if its depth were compressed or stretched; on the
    normalised input that multiplies log(depth / median) by exp(u)."""
    folds: int = 5
    """Cross-validation folds, split by procedure (0 or 1: no cross-validation)."""
    seed: int = 0
    """Random seed (initialisation, sampling, fold split)."""

    def __post_init__(self) -> None:
        if self.seed < 0 or self.folds < 0:
            raise ValueError(f"seed and folds must be >= 0, got {self.seed} and {self.folds}")
        if self.travel_gap < 0:
            raise ValueError(f"travel_gap must be 0 (off) or a positive frame gap, got "
                             f"{self.travel_gap}")
        if not self.frame_rate > 0:
            raise ValueError(f"frame_rate must be positive, got {self.frame_rate}")
        if self.travel_hops < 0:
            raise ValueError(f"travel_hops must be 0 (off) or a positive count, got "
                             f"{self.travel_hops}")
        if self.depth_power < 0:
            raise ValueError(f"depth_power must be >= 0 (0: off), got {self.depth_power}")
        for name in ("frame_loss", "segment_loss"):
            if getattr(self, name) not in ("l1", "l2"):
                raise ValueError(f"{name} must be 'l1' or 'l2', got {getattr(self, name)!r}")
        if self.frame_precision not in ("float32", "bfloat16"):
            raise ValueError(f"frame_precision must be 'float32' or 'bfloat16', got "
                             f"{self.frame_precision!r}")
        if self.field_of_view not in ("none", "predicted", "true"):
            raise ValueError(f"field_of_view must be 'none', 'predicted' or 'true', got "
                             f"{self.field_of_view!r}")
        if not 0 <= self.view_hidden < 1 or (self.view_hidden and self.field_of_view == "none"):
            raise ValueError(f"view_hidden must be in [0, 1), and 0 without a field of view, "
                             f"got {self.view_hidden} with field_of_view "
                             f"{self.field_of_view!r}")

    @property
    def travel_size(self) -> int:
        """Per-frame travel values fed to the per-frame network: 4, 8 with travel_hops, 0 when
        travel_gap is 0."""
        return TRAVEL_SIZE * (1 + (self.travel_hops > 0)) if self.travel_gap else 0

    @property
    def cue_size(self) -> int:
        """Per-frame values beside the depth: the travel, the field of view, the depth
        scale."""
        return self.travel_size + self.view_size + int(self.depth_scale)

    @property
    def view_size(self) -> int:
        """Per-frame field-of-view values: 0 without, 2, 3 with view_hidden (the 'known'
        value)."""
        return 0 if self.field_of_view == "none" else VIEW_SIZE + (self.view_hidden > 0)

    def travel_frames(self, fps: float) -> int:
        """The travel gap, the same time in frames of a video at `fps` (0: no travel input)."""
        return max(1, round(self.travel_gap * fps / self.frame_rate)) if self.travel_gap else 0

    @property
    def feature_size(self) -> int:
        """F: length of a per-frame feature vector."""
        return self.frame_channels[-1]

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict) -> CoverageConfig:
        known = {f.name for f in fields(cls)}
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in data.items() if k in known}
        values.setdefault("travel_gap", 0)  # saved before the travel input: depth only
        values.setdefault("travel_hops", 0)  # saved before the longer travel
        values.setdefault("frame_loss", "l2")  # saved before the loss could be chosen
        values.setdefault("segment_loss", "l2")
        return cls(**values)


COVERAGE_PRESETS: dict[str, CoverageConfig] = {
    "fast": CoverageConfig(frame_loss="l1"),
    "paper": CoverageConfig(
        preset="paper", height=320, width=384,
        frame_channels=(64, 256, 512, 1024, 2048), frame_blocks=(3, 4, 6, 3), bottleneck=True,
        frame_epochs=20, frame_batch=32, frame_lr=3e-4,
    ),
}
"""`fast`: a small ResNet on 64x80 depth, F = 128, L1 per frame (docs/coverage.md, "The L1
loss per frame"). `paper`: ResNet-50 at 320x384, F = 2048, L2 per frame as in the paper."""


def coverage_config(preset: str, **overrides) -> CoverageConfig:
    if preset not in COVERAGE_PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose one of {sorted(COVERAGE_PRESETS)}")
    config = replace(COVERAGE_PRESETS[preset],
                     **{k: v for k, v in overrides.items() if v is not None})
    if config.input_depth not in ("predicted", "true"):
        raise ValueError(f"input_depth must be 'predicted' or 'true', got {config.input_depth!r}")
    return config
