#!/usr/bin/env python3
"""Reference decoding of the COCO YOLOv5s-seg model for the semantic tests,
written independently of the C++ decoder (numpy, following the recipe of
../shared/models/README.md step by step, in network space):

  letterbox to 320 (aspect kept, centred, pad 114), RGB/255 -> OpenCV dnn ->
  score = objectness x class prob >= 0.25 -> class-aware NMS 0.45 ->
  mask = sigmoid(coeffs . protos) at 80x80 -> upsample to 320 -> zero outside
  the box -> cut the letterbox border -> resize to the image -> > 0.5.

Writes <image>_coco_reference.png (instance i's pixels = i + 1, painted best
last) and <image>_coco_reference.txt (one line per instance:
class score x1 y1 x2 y2 area, boxes in image pixels).
Needs python3 with cv2 (Debian: python3-opencv) and numpy.

usage: make_yolo_reference.py MODEL.onnx IMAGE.png OUT_PREFIX
"""
import sys

import cv2
import numpy as np


def letterbox(img, size=320, pad=114):
    h, w = img.shape[:2]
    r = min(size / w, size / h)
    nw, nh = int(round(w * r)), int(round(h * r))
    top, left = (size - nh) // 2, (size - nw) // 2
    canvas = np.full((size, size, 3), pad, np.uint8)
    canvas[top:top + nh, left:left + nw] = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR)
    return canvas, (left, top, nw, nh)


def nms_per_class(boxes, scores, classes, iou_thr):
    order = np.lexsort((np.arange(len(scores)), -scores))
    keep = []
    for i in order:
        ok = True
        for k in keep:
            if classes[k] != classes[i]:
                continue
            x1 = max(boxes[i, 0], boxes[k, 0]); y1 = max(boxes[i, 1], boxes[k, 1])
            x2 = min(boxes[i, 2], boxes[k, 2]); y2 = min(boxes[i, 3], boxes[k, 3])
            inter = max(0.0, x2 - x1) * max(0.0, y2 - y1)
            area = lambda b: (b[2] - b[0]) * (b[3] - b[1])
            if inter / (area(boxes[i]) + area(boxes[k]) - inter) > iou_thr:
                ok = False
                break
        if ok:
            keep.append(i)
    return keep[:100]


def main():
    model, image, prefix = sys.argv[1:4]
    img = cv2.imread(image, cv2.IMREAD_COLOR)
    h, w = img.shape[:2]
    boxed, (left, top, nw, nh) = letterbox(img)
    rgb = cv2.cvtColor(boxed, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    net = cv2.dnn.readNetFromONNX(model)
    net.setInput(rgb.transpose(2, 0, 1)[None], "images")
    det, protos = net.forward(["output0", "output1"])
    det, protos = det[0], protos[0]
    nc = det.shape[1] - 5 - protos.shape[0]
    cls = det[:, 5:5 + nc]
    best = cls.argmax(1)
    score = det[:, 4] * cls[np.arange(len(det)), best]
    sel = np.where((det[:, 4] >= 0.25) & (score >= 0.25))[0]
    xyxy = np.stack([det[sel, 0] - det[sel, 2] / 2, det[sel, 1] - det[sel, 3] / 2,
                     det[sel, 0] + det[sel, 2] / 2, det[sel, 1] + det[sel, 3] / 2], 1)
    keep = nms_per_class(xyxy, score[sel], best[sel], 0.45)
    labels = np.zeros((h, w), np.uint8)
    lines = []
    sx, sy = w / nw, h / nh
    for rank in reversed(range(len(keep))):  # best painted last
        j = keep[rank]
        i = sel[j]
        coeffs = det[i, 5 + nc:]
        m = 1 / (1 + np.exp(-(coeffs @ protos.reshape(protos.shape[0], -1))))
        m = cv2.resize(m.reshape(protos.shape[1:]).astype(np.float32), (320, 320), interpolation=cv2.INTER_LINEAR)
        x1, y1, x2, y2 = xyxy[j]
        cols, rows = np.arange(320) + 0.5, np.arange(320) + 0.5
        inside = ((rows[:, None] >= y1) & (rows[:, None] < y2) & (cols[None] >= x1) & (cols[None] < x2))
        m = m * inside
        m = cv2.resize(m[top:top + nh, left:left + nw], (w, h), interpolation=cv2.INTER_LINEAR)
        mask = m > 0.5
        labels[mask] = rank + 1
        box = [(x1 - left) * sx, (y1 - top) * sy, (x2 - left) * sx, (y2 - top) * sy]
        lines.append((rank, f"{best[i]} {score[i]:.5f} {box[0]:.2f} {box[1]:.2f} {box[2]:.2f} {box[3]:.2f} "
                            f"{int(mask.sum())}"))
    cv2.imwrite(prefix + ".png", labels)
    with open(prefix + ".txt", "w") as f:
        f.write("# class score x1 y1 x2 y2 area (best first); written by make_yolo_reference.py\n")
        for _, line in sorted(lines):
            f.write(line + "\n")
    print(open(prefix + ".txt").read())


if __name__ == "__main__":
    main()
