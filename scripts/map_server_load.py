#!/usr/bin/env python3
"""Loads a ROS map_server map (YAML + image) by the rules map_server documents, for issue 19's
check that mapmerge's maps load as ROS loads them. Standard library only.

Rules (wiki.ros.org/map_server, "YAML format" and "Value Interpretation"; nav2_map_server
keeps them):
- `image` is relative to the YAML file's folder unless absolute;
- a pixel's colour value x in [0, 255] (the mean of the channels; a PGM has one) becomes
  p = (255 - x) / 255.0, or x / 255.0 when `negate` is 1;
- `mode: trinary` (the default): p > occupied_thresh -> 100 (occupied), p < free_thresh -> 0
  (free), else -1 (unknown);
  `mode: scale`: occupied and free as trinary, otherwise 99 * (p - free_thresh) /
  (occupied_thresh - free_thresh); `mode: raw`: the value x itself;
- the image's first row is the map's last (top) row; `origin` is the pose of the lower-left
  pixel.

usage: map_server_load.py MAP.yaml   prints one JSON object: width, height, resolution,
origin, occupied, free, unknown (cell counts), other (cells of neither, in scale/raw mode).
"""

import json
import os
import sys


def parse_yaml(text):
    """The flat `key: value` YAML map_server files use (origin as a [x, y, yaw] list)."""
    fields = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or ":" not in line:
            continue
        key, value = (part.strip() for part in line.split(":", 1))
        if value.startswith("["):
            fields[key] = [float(v) for v in value.strip("[]").split(",")]
        else:
            fields[key] = value.strip("'\"")
    return fields


def read_pgm(path):
    """(width, height, maxval, pixels) of a binary (P5) or plain (P2) PGM."""
    data = open(path, "rb").read()
    tokens, position = [], 0
    while len(tokens) < 4:
        while data[position:position + 1].isspace():
            position += 1
        if data[position:position + 1] == b"#":
            while data[position:position + 1] not in (b"\n", b""):
                position += 1
            continue
        start = position
        while not data[position:position + 1].isspace():
            position += 1
        tokens.append(data[start:position].decode())
    magic, width, height, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    if magic == "P5":
        body = data[position + 1:]
        if maxval < 256:
            pixels = list(body[: width * height])
        else:
            pixels = [int.from_bytes(body[2 * i:2 * i + 2], "big") for i in range(width * height)]
    elif magic == "P2":
        pixels = [int(v) for v in data[position:].split()[: width * height]]
    else:
        raise SystemExit(f"{path}: not a PGM ({magic})")
    if len(pixels) != width * height:
        raise SystemExit(f"{path}: {len(pixels)} pixels for {width}x{height}")
    return width, height, maxval, pixels


def load(yaml_path):
    fields = parse_yaml(open(yaml_path).read())
    image = fields["image"]
    if not os.path.isabs(image):
        image = os.path.join(os.path.dirname(os.path.abspath(yaml_path)), image)
    width, height, maxval, pixels = read_pgm(image)
    negate = int(fields.get("negate", 0))
    occupied_thresh = float(fields["occupied_thresh"])
    free_thresh = float(fields["free_thresh"])
    mode = fields.get("mode", "trinary")
    counts = dict(occupied=0, free=0, unknown=0, other=0)
    for pixel in pixels:
        x = pixel * 255.0 / maxval
        if mode == "raw":
            value = round(x)
        else:
            p = x / 255.0 if negate else (255.0 - x) / 255.0
            if p > occupied_thresh:
                value = 100
            elif p < free_thresh:
                value = 0
            elif mode == "scale":
                value = 99 * (p - free_thresh) / (occupied_thresh - free_thresh)
            else:
                value = -1
        if value == 100:
            counts["occupied"] += 1
        elif value == 0:
            counts["free"] += 1
        elif value == -1:
            counts["unknown"] += 1
        else:
            counts["other"] += 1
    return dict(width=width, height=height, resolution=float(fields["resolution"]),
                origin=fields["origin"], **counts)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    print(json.dumps(load(sys.argv[1])))
