#!/usr/bin/env python3
"""Writes tiny_semantic.onnx: a hand-made 3-class "semantic segmentation"
network for the tests of the per-pixel argmax decoder (no real PASCAL VOC
model is available here). Input `image` [1,3,16,16] RGB in [0,1]; output
`scores` [1,3,8,8] (NCHW, a 1x1 convolution then 2x2 average pooling):
  class 0 "background" = 0.5 (constant),
  class 1 "person"     = 2*R - G - B   (red pixels),
  class 2 "car"        = 2*B - R - G   (blue pixels).
So red -> person, blue -> car, grey/black -> background.
Requires the `onnx` package (pip install onnx). Run from this folder."""
import onnx
from onnx import TensorProto, helper

weights = [0, 0, 0,
           2, -1, -1,
           -1, -1, 2]
w = helper.make_tensor("w", TensorProto.FLOAT, [3, 3, 1, 1], [float(v) for v in weights])
b = helper.make_tensor("b", TensorProto.FLOAT, [3], [0.5, 0.0, 0.0])
conv = helper.make_node("Conv", ["image", "w", "b"], ["conv"], kernel_shape=[1, 1])
pool = helper.make_node("AveragePool", ["conv"], ["scores"], kernel_shape=[2, 2], strides=[2, 2])
graph = helper.make_graph(
    [conv, pool], "tiny_semantic",
    [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 16, 16])],
    [helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, 3, 8, 8])],
    [w, b])
model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 11)], producer_name="stillpoint")
model.ir_version = 6
onnx.checker.check_model(model)
onnx.save(model, "tiny_semantic.onnx")
print("wrote tiny_semantic.onnx")
