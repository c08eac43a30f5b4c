"""The network: StereoGeoNet in torch (``model``, ``checkpoint``, ``export``) and its ONNX runtime.

Only the runtime is imported here, so ``import stereogeo_cli.network`` never imports torch.
"""

from stereogeo_cli.network.runtime import FieldNetwork, NetworkOutput, ViewFields, cell_pixel_coordinates

__all__ = ["FieldNetwork", "NetworkOutput", "ViewFields", "cell_pixel_coordinates"]
