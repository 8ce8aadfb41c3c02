"""Byte codecs of the simulator role of the activemap pipeline (see ../BRIDGE.md).

Standard library only. An external simulator (Habitat, a real robot driver) uses these to
publish what the built-in `sim` node publishes and to read the actions it is sent:

- ``encode_rgbd``: the RgbdFrame payload (64-byte header, RGB8, float32 depth in metres);
- ``encode_true_pose`` / ``encode_episode_status``: small messages (u16 version + postcard);
- ``decode_action``: the follower's Action message.

The layouts mirror schemas/src/rgbd.rs, schemas/src/small.rs and schemas/src/messages.rs, and a
Rust test (sim-bridge/src/tests/bridge_tests.rs) checks these codecs against that crate.
"""

import struct

RGBD_MAGIC = int.from_bytes(b"RGBD", "little")
RGBD_VERSION = 1
RGBD_HEADER = struct.Struct("<IIQdddddII")  # 64 bytes
ACTIONS = ("forward", "turn_left", "turn_right", "stop")
EPISODE_STATES = ("running", "finished", "failed")


def _align8(n):
    return (n + 7) // 8 * 8


def rgbd_payload_len(width, height):
    """Total RgbdFrame payload size: header, RGB and depth sections, each 8-byte aligned."""
    rgb_at = _align8(RGBD_HEADER.size)
    depth_at = _align8(rgb_at + width * height * 3)
    return _align8(depth_at + width * height * 4)


def encode_rgbd(frame_id, stamp, intrinsics, width, height, rgb, depth):
    """RgbdFrame payload. ``intrinsics`` = (fx, fy, cx, cy) in pixels (OpenCV, pixel centres at
    integer coordinates); ``rgb``: width*height*3 bytes, row-major from the top-left;
    ``depth``: width*height float32 little-endian bytes, or a sequence of floats, z-depth in
    metres, 0 = no reading."""
    fx, fy, cx, cy = intrinsics
    n = width * height
    if len(rgb) != 3 * n:
        raise ValueError(f"rgb has {len(rgb)} bytes, expected {3 * n}")
    if not isinstance(depth, (bytes, bytearray)):
        depth = struct.pack(f"<{n}f", *depth)
    if len(depth) != 4 * n:
        raise ValueError(f"depth has {len(depth)} bytes, expected {4 * n}")
    out = bytearray(rgbd_payload_len(width, height))
    RGBD_HEADER.pack_into(out, 0, RGBD_MAGIC, RGBD_VERSION, frame_id, stamp, fx, fy, cx, cy, width, height)
    rgb_at = _align8(RGBD_HEADER.size)
    depth_at = _align8(rgb_at + 3 * n)
    out[rgb_at:rgb_at + 3 * n] = rgb
    out[depth_at:depth_at + 4 * n] = depth
    return bytes(out)


def _varint(value):
    """Postcard's unsigned LEB128 varint."""
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _read_varint(data, at):
    value, shift = 0, 0
    while True:
        if at >= len(data):
            raise ValueError("truncated varint")
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


def _small(version, body):
    return struct.pack("<H", version) + body


def encode_true_pose(frame_id, stamp, translation, rotation_xyzw):
    """TruePose (evaluation only): T_world_camera as translation (m) and quaternion (x, y, z, w)."""
    return _small(1, _varint(frame_id) + struct.pack("<d3d4d", stamp, *translation, *rotation_xyzw))


def encode_episode_status(step, max_steps, state, message=""):
    """EpisodeStatus; ``state`` in EPISODE_STATES."""
    text = message.encode("utf-8")
    body = _varint(step) + _varint(max_steps) + _varint(EPISODE_STATES.index(state))
    return _small(1, body + _varint(len(text)) + text)


def decode_action(payload):
    """Action -> (step, name) with name in ACTIONS. Raises ValueError on a malformed payload."""
    if len(payload) < 2 or struct.unpack_from("<H", payload)[0] != 1:
        raise ValueError("not an Action v1 payload")
    step, at = _read_varint(payload, 2)
    kind, at = _read_varint(payload, at)
    if kind >= len(ACTIONS) or at != len(payload):
        raise ValueError("malformed Action payload")
    return step, ACTIONS[kind]


def encode_action(step, name):
    """Action (for tests and for driving a simulator by hand)."""
    return _small(1, _varint(step) + _varint(ACTIONS.index(name)))
