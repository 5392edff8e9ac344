"""ONNX Runtime YOLO detector: letterbox -> network -> decode (v8 + NMS, or v10) -> image boxes."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort
from weldcell.sdk.errors import DataError
from weldcell.sdk.stages import Detection2D


class OnnxDetector:
    """``detector.onnx``: ``(rgb, meta) -> list[Detection2D]`` (``meta`` is ignored)."""

    def __init__(self, settings) -> None:
        self.s = settings
        path = Path(settings.model)
        if not path.is_file():
            raise DataError(
                f"ONNX model {path} does not exist",
                "export your trained YOLO model (`yolo export model=best.pt format=onnx`) and set "
                '[stages.detector.settings] model = "path/to/best.onnx"',
            )
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = settings.threads
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as e:  # noqa: BLE001 - onnxruntime raises its own exception types
            raise DataError(f"ONNX Runtime cannot load {path}: {e}", "give a valid .onnx file") from None
        inp = self.session.get_inputs()[0]
        self.input_name = inp.name
        shape = inp.shape
        if len(shape) != 4 or (isinstance(shape[1], int) and shape[1] != 3):
            raise DataError(
                f"ONNX model {path} takes input {shape}, not (1, 3, H, W)",
                "export the detector with an image input (N, 3, H, W)",
            )
        self.size = settings.input_size
        if isinstance(shape[2], int) and isinstance(shape[3], int):
            self.size = int(shape[2])

    def _letterbox(self, rgb: np.ndarray) -> tuple[np.ndarray, float, tuple[float, float]]:
        h, w = rgb.shape[:2]
        r = self.size / max(h, w)
        nh, nw = round(h * r), round(w * r)
        img = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
        canvas = np.full((self.size, self.size, 3), 114, np.uint8)
        top, left = (self.size - nh) // 2, (self.size - nw) // 2
        canvas[top : top + nh, left : left + nw] = img
        x = canvas.transpose(2, 0, 1)[None].astype(np.float32) / 255.0
        return x, r, (left, top)

    def __call__(self, rgb: np.ndarray, meta: dict | None = None) -> list[Detection2D]:
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise DataError(
                f"detector.onnx needs an RGB image (H, W, 3), got {rgb.shape}", "pass a colour image"
            )
        x, r, (left, top) = self._letterbox(rgb)
        out = np.asarray(self.session.run(None, {self.input_name: x})[0])
        boxes, scores, cls = self._decode(out)
        keep = scores >= self.s.score_threshold
        boxes, scores, cls = boxes[keep], scores[keep], cls[keep]
        boxes = (boxes - [left, top, left, top]) / r
        h, w = rgb.shape[:2]
        boxes = np.clip(boxes, 0, [w - 1, h - 1, w - 1, h - 1])
        dets = []
        for b, s, c in zip(boxes, scores, cls, strict=True):
            label = self.s.classes[c] if c < len(self.s.classes) else f"class{c}"
            if self.s.keep_classes and label not in self.s.keep_classes:
                continue
            dets.append(Detection2D(tuple(map(float, b)), label, int(c), float(s)))
        return dets

    def _decode(self, out: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        kind = self.s.output
        nc = len(self.s.classes)
        if kind == "auto":
            if out.ndim == 3 and out.shape[2] == 6:
                kind = "yolov10"
            elif out.ndim == 3 and out.shape[1] == 4 + nc:
                kind = "yolov8"
            else:
                raise DataError(
                    f"detector.onnx: output shape {out.shape} is neither YOLOv8 (1, 4+{nc}, N) "
                    "nor YOLOv10 (1, N, 6)",
                    "check `classes` (their number must match the model) or set `output`",
                )
        if kind == "yolov10":
            if out.ndim != 3 or out.shape[2] != 6:
                raise DataError(
                    f"detector.onnx: YOLOv10 output must be (1, N, 6), got {out.shape}",
                    "set output = 'yolov8' or 'auto' for this model",
                )
            o = out[0]
            return o[:, :4].astype(float), o[:, 4].astype(float), o[:, 5].astype(int)
        if out.ndim != 3 or out.shape[1] != 4 + nc:
            raise DataError(
                f"detector.onnx: YOLOv8 output must be (1, 4+{nc}, N), got {out.shape}",
                "list every class the model was trained on in `classes`",
            )
        o = out[0].T
        cxcywh, cls_scores = o[:, :4], o[:, 4:]
        cls = np.argmax(cls_scores, axis=1)
        scores = cls_scores[np.arange(len(o)), cls]
        xyxy = np.column_stack(
            [
                cxcywh[:, 0] - cxcywh[:, 2] / 2,
                cxcywh[:, 1] - cxcywh[:, 3] / 2,
                cxcywh[:, 0] + cxcywh[:, 2] / 2,
                cxcywh[:, 1] + cxcywh[:, 3] / 2,
            ]
        )
        keep = scores >= self.s.score_threshold
        xyxy, scores, cls = xyxy[keep], scores[keep], cls[keep]
        if not len(xyxy):
            return np.zeros((0, 4)), np.zeros(0), np.zeros(0, int)
        # class-aware NMS (OpenCV): offset boxes per class so classes never suppress each other
        off = cls[:, None] * 10000.0
        b = xyxy + off
        idx = cv2.dnn.NMSBoxes(
            np.column_stack([b[:, :2], b[:, 2:] - b[:, :2]]).tolist(),
            scores.tolist(),
            self.s.score_threshold,
            self.s.iou_threshold,
        )
        idx = np.asarray(idx, int).ravel()
        return xyxy[idx], scores[idx], cls[idx]
