"""CDR bytes for the record's ROS 2 messages, a batch of ticks at once.

Every message the recorder writes has a fixed size (its strings and sequence lengths are fixed
for a run: the frame names, the joint names), so its CDR encoding (little endian, the 4-byte
encapsulation header ``00 01 00 00``, each primitive aligned to its size from the end of that
header) is one byte template with numbers at fixed offsets. :class:`Layout` builds the template
once; :meth:`Layout.encode` fills a whole batch with numpy (one structured array over ``n``
copies of the template) and hands back each message's bytes. The mcap-ros2-support decoder reads
them back (the tests check it); no per-message Python serialiser runs in the writer's thread.
"""

from __future__ import annotations

import struct

import numpy as np

ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little endian


class Layout:
    """A fixed-size CDR message: literal parts (strings, sequence lengths) and named number
    fields (a name may appear at several offsets: every copy is filled with the same column)."""

    def __init__(self) -> None:
        self._buf = bytearray(ENCAPSULATION)
        self._fields: list[tuple[str, int, str, int | None]] = []  # name, offset, format, count (None: one)
        self._dtype: list | None = None

    @property
    def size(self) -> int:
        return len(self._buf)

    def _align(self, n: int) -> None:
        self._buf += b"\0" * ((-(len(self._buf) - 4)) % n)

    def _field(self, name: str, fmt: str, size: int, count: int | None = None) -> None:
        self._align(size)
        self._fields.append((name, len(self._buf), fmt, count))
        self._buf += b"\0" * (size * (count or 1))

    def i32(self, name: str) -> Layout:
        self._field(name, "<i4", 4)
        return self

    def u32(self, name: str) -> Layout:
        self._field(name, "<u4", 4)
        return self

    def f64(self, name: str, count: int | None = None) -> Layout:
        self._field(name, "<f8", 8, count)
        return self

    def u32_literal(self, value: int) -> Layout:
        self._align(4)
        self._buf += struct.pack("<I", value)
        return self

    def string(self, s: str) -> Layout:
        b = s.encode() + b"\0"
        self.u32_literal(len(b))
        self._buf += b
        return self

    def header(self, frame_id: str) -> Layout:
        """std_msgs/Header: stamp (``sec``, ``nanosec`` fields) and a fixed frame id."""
        return self.i32("sec").u32("nanosec").string(frame_id)

    def _compile(self) -> list[tuple[str, int, int, str, int | None]]:
        if self._dtype is None:
            self._dtype = [(name, off, off + np.dtype(fmt).itemsize * (count or 1), fmt, count)
                           for name, off, fmt, count in self._fields]
            self._template = np.frombuffer(bytes(self._buf), dtype=np.uint8)
        return self._dtype

    def encode(self, n: int, columns: dict) -> list[bytes]:
        """``n`` messages, the named fields from ``columns`` (name -> array (n,) or (n, count));
        fields not given keep the template's zeros. Returns each message's bytes."""
        fields = self._compile()
        size = len(self._template)
        buf = np.empty((n, size), dtype=np.uint8)
        buf[:] = self._template
        for name, a, b, fmt, _count in fields:
            col = columns.get(name)
            if col is not None:
                view = buf[:, a:b].view(fmt)
                view[...] = np.reshape(col, view.shape)
        blob = buf.tobytes()
        return [blob[k * size:(k + 1) * size] for k in range(n)]


def stamp(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(log time ns (int64), sec (int32), nanosec (uint32)) of simulated times ``t_s`` (s)."""
    ns = np.rint(np.asarray(t_s, dtype=float) * 1e9).astype(np.int64)
    return ns, (ns // 1_000_000_000).astype(np.int32), (ns % 1_000_000_000).astype(np.uint32)


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (n, 4: x, y, z, w; w >= 0) of rotation matrices ``R`` (n, 3, 3): for each,
    the candidate of Shepperd's method with the largest diagonal term (no branch per row)."""
    R = np.asarray(R, dtype=float).reshape(-1, 3, 3)
    n = len(R)
    m00, m11, m22 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    a, b, c = R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]
    d, e, f = R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]
    t = np.stack((1.0 + m00 - m11 - m22, 1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22, 1.0 + m00 + m11 + m22), 1)
    Q = np.empty((n, 4, 4))  # candidate k is 4 q_k q: largest when q_k is
    Q[:, 0] = np.stack((t[:, 0], d, e, a), 1)
    Q[:, 1] = np.stack((d, t[:, 1], f, b), 1)
    Q[:, 2] = np.stack((e, f, t[:, 2], c), 1)
    Q[:, 3] = np.stack((a, b, c, t[:, 3]), 1)
    q = Q[np.arange(n), np.argmax(t, axis=1)]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 3] < 0] *= -1.0
    return q


def rotation(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of quaternions ``q`` (n, 4: x, y, z, w)."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    x, y, z, w = q.T
    return np.stack((
        np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), 1),
        np.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), 1),
        np.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), 1),
    ), 1)


def pose_stamped(frame: str) -> Layout:
    return Layout().header(frame).f64("p", 3).f64("q", 4)


def twist_stamped(frame: str) -> Layout:
    return Layout().header(frame).f64("v", 3).f64("w", 3)


def wrench_stamped(frame: str) -> Layout:
    return Layout().header(frame).f64("f", 3).f64("tau", 3)


def joint_state(names: list[str], velocity: bool = True) -> Layout:
    """sensor_msgs/JointState with ``names``, ``position`` and (``velocity``) velocities; no effort."""
    lay = Layout().header("")
    lay.u32_literal(len(names))
    for n in names:
        lay.string(n)
    lay.u32_literal(len(names))
    if names:
        lay.f64("position", len(names))
    k = len(names) if velocity else 0
    lay.u32_literal(k)
    if k:
        lay.f64("velocity", k)
    return lay.u32_literal(0)  # effort: none


def tf_message(parent_child: list[tuple[str, str]]) -> Layout:
    """tf2_msgs/TFMessage of one transform per (parent, child), fields ``p<k>``, ``q<k>``."""
    lay = Layout().u32_literal(len(parent_child))
    for k, (parent, child) in enumerate(parent_child):
        lay.header(parent).string(child).f64(f"p{k}", 3).f64(f"q{k}", 4)
    return lay
