"""``detector.onnx``: a YOLO-family weld-region detector exported to ONNX, run with ONNX Runtime
(YOLOv8-style raw outputs with NMS, YOLOv10-style NMS-free outputs). Bring your own weights: see
docs/methods/mapping.md ("Your own detector")."""

from __future__ import annotations

from weldcell.sdk.descriptors import StageSpec
from weldcell.sdk.hookspecs import hookimpl


@hookimpl
def weldcell_register_stages(register) -> None:
    from weldcell.plugins.onnx_detector import settings

    register(
        StageSpec(
            name="detector.onnx",
            kind="detector",
            summary="YOLOv8/YOLOv10 ONNX model on ONNX Runtime (model path and class names from the profile)",
            settings=settings.OnnxDetectorSettings,
            factory=_factory,
            requires={"onnxruntime": "onnx"},
        )
    )


def _factory(settings):
    from weldcell.plugins.onnx_detector.detector import OnnxDetector

    return OnnxDetector(settings)
