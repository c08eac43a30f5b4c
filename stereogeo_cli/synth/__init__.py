"""Synthetic stereo pairs with exact ground truth, rendered on the CPU (moderngl + EGL + Mesa llvmpipe).

    from stereogeo_cli.synth import SynthConfig, sample_pair
    sample = sample_pair(seed=0, index=12, config=SynthConfig(depth=True))
    sample.left, sample.right, sample.calib, sample.depth_left

``make_dataset`` writes the project's dataset layout (left/, right/, calib.jsonl); the torch stream
is ``stereogeo_cli.synth.stream.SyntheticStereoStream`` (imported separately: it needs torch).
``make_sequence`` renders one moving rig's sequence (left/, right/, calib.json with per-frame poses) and
``read_sequence_ground_truth`` reads such a folder, rendered or real (``stereogeo_cli.synth.sequence``).
"""

from stereogeo_cli.synth.check import DepthAgreement, depth_agreement
from stereogeo_cli.synth.config import SynthConfig
from stereogeo_cli.synth.dataset import make_dataset
from stereogeo_cli.synth.sample import StereoSample, sample_id, sample_pair
from stereogeo_cli.synth.sequence import make_sequence, read_sequence_ground_truth, sequence_config

__all__ = [
    "DepthAgreement",
    "StereoSample",
    "SynthConfig",
    "depth_agreement",
    "make_dataset",
    "make_sequence",
    "read_sequence_ground_truth",
    "sample_id",
    "sample_pair",
    "sequence_config",
]
