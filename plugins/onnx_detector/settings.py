"""Settings of ``detector.onnx``."""

from __future__ import annotations

from typing import Literal

from pydantic import Field
from weldcell.sdk.settings import Settings


class OnnxDetectorSettings(Settings):
    """A YOLO-family detector exported to ONNX (``yolo export format=onnx``)."""

    model: str = Field(description="path of the .onnx file (relative paths: to the working directory)")
    classes: list[str] = Field(
        default_factory=lambda: ["weld-region"], description="class names, in model order"
    )
    output: Literal["auto", "yolov8", "yolov10"] = Field(
        "auto",
        description="'yolov8': (1, 4+C, N) raw boxes + class scores, NMS here; 'yolov10': (1, N, 6) "
        "x1 y1 x2 y2 score class, NMS-free; 'auto': decided from the output shape",
    )
    input_size: int = Field(640, ge=32, le=4096, description="square network input [px] (letterboxed)")
    score_threshold: float = Field(0.25, ge=0, le=1, description="minimum score")
    iou_threshold: float = Field(0.45, gt=0, le=1, description="NMS IoU threshold (yolov8)")
    keep_classes: list[str] | None = Field(None, description="report only these classes (default: all)")
    threads: int = Field(1, ge=1, le=16, description="ONNX Runtime intra-op threads")
