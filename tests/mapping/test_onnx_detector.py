"""detector.onnx on small ONNX graphs built here whose outputs are known (YOLOv8 and YOLOv10 styles)."""

from __future__ import annotations

import numpy as np
import pytest

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402
from weldcell.plugins.onnx_detector.detector import OnnxDetector  # noqa: E402
from weldcell.plugins.onnx_detector.settings import OnnxDetectorSettings  # noqa: E402
from weldcell.sdk.errors import DataError  # noqa: E402


def _model(path, out: np.ndarray, size: int = 64) -> str:
    """A graph: image (1, 3, size, size) -> constant ``out`` (+ 0 x mean(image), so the input is used)."""
    img = helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])
    y = helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(out.shape))
    nodes = [
        helper.make_node("Constant", [], ["c"], value=numpy_helper.from_array(out.astype(np.float32))),
        helper.make_node("ReduceMean", ["images"], ["m"], keepdims=0),
        helper.make_node("Constant", [], ["zero"], value=numpy_helper.from_array(np.float32(0.0))),
        helper.make_node("Mul", ["m", "zero"], ["z"]),
        helper.make_node("Add", ["c", "z"], ["output0"]),
    ]
    g = helper.make_graph(nodes, "det", [img], [y])
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
    m.ir_version = 8
    onnx.checker.check_model(m)
    p = path / "det.onnx"
    onnx.save(m, str(p))
    return str(p)


def test_yolov8_outputs_are_decoded_with_nms(tmp_path):
    # 2 classes, 3 candidates in the 64x64 letterboxed input: two overlapping boxes of class 1, one of class 0
    out = np.zeros((1, 6, 3))
    out[0, :4, 0] = [20, 20, 10, 10]
    out[0, 5, 0] = 0.9
    out[0, :4, 1] = [21, 20, 10, 10]
    out[0, 5, 1] = 0.8  # suppressed by NMS
    out[0, :4, 2] = [40, 40, 8, 8]
    out[0, 4, 2] = 0.7
    det = OnnxDetector(OnnxDetectorSettings(model=_model(tmp_path, out), classes=["plate", "joint"]))
    rgb = np.zeros((32, 64, 3), np.uint8)  # letterbox: scale 1, 16 px padding at the top
    got = sorted(det(rgb), key=lambda d: -d.score)
    assert [(d.label, round(d.score, 2)) for d in got] == [("joint", 0.9), ("plate", 0.7)]
    np.testing.assert_allclose(got[0].xyxy, [15, 0, 25, 9], atol=1e-4)  # y clipped to the image
    np.testing.assert_allclose(got[1].xyxy, [36, 20, 44, 28], atol=1e-4)


def test_yolov10_outputs_need_no_nms(tmp_path):
    out = np.array([[[10, 20, 30, 40, 0.95, 0], [0, 0, 5, 5, 0.1, 0]]], dtype=np.float32)
    det = OnnxDetector(OnnxDetectorSettings(model=_model(tmp_path, out), classes=["weld-region"]))
    got = det(np.zeros((64, 64, 3), np.uint8))
    assert len(got) == 1 and got[0].label == "weld-region"
    np.testing.assert_allclose(got[0].xyxy, [10, 20, 30, 40])


def test_wrong_output_shape_is_one_clear_error(tmp_path):
    out = np.zeros((1, 7, 5))  # 3 classes, but the profile lists 1
    det = OnnxDetector(OnnxDetectorSettings(model=_model(tmp_path, out), classes=["weld-region"]))
    with pytest.raises(DataError, match="neither YOLOv8"):
        det(np.zeros((64, 64, 3), np.uint8))


def test_nothing_found_is_an_empty_list(tmp_path):
    out = np.zeros((1, 5, 4))
    det = OnnxDetector(OnnxDetectorSettings(model=_model(tmp_path, out), classes=["weld-region"]))
    assert det(np.zeros((64, 64, 3), np.uint8)) == []


def test_missing_model_file_says_how_to_export(tmp_path):
    with pytest.raises(DataError, match="export"):
        OnnxDetector(OnnxDetectorSettings(model=str(tmp_path / "none.onnx")))
