#!/usr/bin/env python3
"""Writes the hand-made seeds of fuzz/corpus/ (the ones not copied from the
repository's own files): emulator-style board transfers and replies, USB
descriptors, small recordings of both format versions, .npy files and
camera-link messages. Usage: make_seeds.py RECORDING.sdirec (a simulator
recording, cut to its first records)."""
import json
import os
import struct
import sys
import zlib

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..")
CORPUS = os.path.join(ROOT, "fuzz", "corpus")


def put(target, name, data):
    d = os.path.join(CORPUS, target)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def raw_quads(dn, quads, frame_number):
    """The emulator's encode_raw_quads: q0 = d, q2 = -d, 12-bit words."""
    out = bytearray()
    for d in dn:
        words = [d & 0xFFF, 0, (-d) & 0xFFF, 0, 0, 0][:quads]
        for w in words:
            out += struct.pack("<H", w)
    out[0] = frame_number
    return bytes(out)


def board_frames():
    # Unstructured reads its integers from the input's front: width 4,
    # height 3, 4 quads, numbers in the first byte, Quad0, no dark, numbers checked.
    w, h = 4, 3
    head = bytes([3, 2, 1, 1, 0, 0, 1])
    frames = b""
    for n in [7, 8, 9, 11, 10, 12]:
        raw = raw_quads([(i * 97) % 4096 - 2048 for i in range(w * h)], 4, n)
        # one frame in two transfers: a full one and a short one
        frames += bytes([len(raw) // 2]) + raw[: len(raw) // 2] + b"\x00"
        frames += bytes([len(raw) - len(raw) // 2]) + raw[len(raw) // 2 :] + b"\x01"
    put("board_frames", "emulator-quads", head + frames)


def board_control():
    # every transfer answered in full (0xFF) with register-like values
    put("board_control", "genuine", bytes([0xFF, 1, 2, 3] * 256))
    put("board_control", "short-replies", bytes([0xFF, 1, 2, 3, 5, 0xFF, 9] * 64))


def descriptors():
    interface = bytes([9, 4, 0, 0, 1, 0xFF, 0, 0, 1])
    bulk_in = bytes([7, 5, 0x82, 2]) + struct.pack("<H", 512) + b"\x00"
    uvc = bytes([9, 4, 0, 0, 1, 0x0E, 0x01, 0, 1, 7, 5, 0x83, 3, 16, 0, 8])
    put("usb_descriptors", "bulk-mode", b"\x00" + interface + bulk_in)
    put("usb_descriptors", "uvc-mode", b"\x00" + uvc)


def record(kind, payload):
    crc = zlib.crc32(bytes([kind]) + struct.pack("<I", len(payload)) + payload)
    return b"SDIR" + bytes([kind]) + struct.pack("<I", len(payload)) + payload + struct.pack("<I", crc)


def recordings(path):
    d = open(path, "rb").read()
    n = struct.unpack("<I", d[8:12])[0]
    at, kept = 16 + n, 0
    while kept < 3:  # header, the dark frame and two frames
        at += 13 + struct.unpack("<I", d[at + 5 : at + 9])[0]
        kept += 1
    end = record(3, struct.pack("<QQ", 2, 0))
    put("recording", "v2-sim", d[:at] + end)
    # version 1: the same header, f32 frames uncompressed, 3 x 2 pixels
    header = json.loads(d[12 : 12 + n])
    header["format_version"] = 1
    header["sensor"]["width"], header["sensor"]["height"] = 3, 2
    text = json.dumps(header).encode()
    v1 = b"SDIREC01" + struct.pack("<I", len(text)) + text + struct.pack("<I", zlib.crc32(text))
    for seq in range(2):
        p = struct.pack("<QQ", seq, 1000 * seq) + bytes([3]) + b"raw" + struct.pack("<II", 3, 2)
        p += struct.pack("<6f", 1.0, -2.0, 3.5, 0.0, 2047.0, -2048.0) + bytes([0, 0, 0, 0, 1, 1])
        v1 += record(1, p)
    put("recording", "v1-small", v1 + end)


def npy():
    def one(version, shape, descr, count, size):
        text = "{'descr': '%s', 'fortran_order': False, 'shape': %s, }" % (descr, shape)
        pre = 10 if version == 1 else 12
        pad = (-(pre + len(text) + 1)) % 64
        text = (text + " " * pad + "\n").encode()
        lenb = struct.pack("<H" if version == 1 else "<I", len(text))
        return b"\x93NUMPY" + bytes([version, 0]) + lenb + text + bytes(count * size)

    put("npy", "f32-2x3x4", one(1, "(2, 3, 4)", "<f4", 24, 4))
    put("npy", "f32-v2-3x2", one(2, "(3, 2)", ">f4", 6, 4))
    put("npy", "f32-scalar", one(1, "()", "<f4", 1, 4))


def camera_link():
    def msg(kind, port=0, wire=0, payload=b"", stamp=0, length=None):
        n = len(payload) if length is None else length
        return bytes([kind, port, wire, 0]) + struct.pack("<IQ", n, stamp) + payload

    hello = msg(1, payload=b"640x480,320x240,30,raw")
    frame = msg(2, 0, 1, bytes(16), stamp=123456)
    data = msg(2, 1, 3, bytes(8), stamp=123457)
    put("camera_link", "sdid-to-camera", hello + frame + data + msg(3, stamp=9) + msg(4, payload=b"two-shot") + msg(5))
    state = msg(18, 1, 3, struct.pack("<QQ", 10, 4))
    put("camera_link", "camera-to-sdid", msg(16) + state + msg(17, payload=b"busy"))


if __name__ == "__main__":
    board_frames()
    board_control()
    descriptors()
    recordings(sys.argv[1])
    npy()
    camera_link()
