"""meshoptimizer bitstream decoder (``EXT_meshopt_compression`` / ``KHR_meshopt_compression``) in numpy.

glTF-Transform (``gltf-transform meshopt``) and gltfpack (``gltfpack -c``) compress every bufferView of a file with
meshoptimizer's codecs and leave a *fallback* buffer without a uri; a loader must decode the views. This module
implements the three modes of the Khronos extension (Appendix A of ``KHR_meshopt_compression``, the bitstream of
zeux/meshoptimizer ``src/vertexcodec.cpp`` / ``src/indexcodec.cpp``) and its four filters (Appendix B,
``src/vertexfilter.cpp``):

* ``ATTRIBUTES`` (vertex codec, header ``0xa0`` version 0 and ``0xa1`` version 1): blocks of at most
  ``min(8192 / stride & ~15, 256)`` elements; per byte of the element a transposed byte stream of 16-byte groups
  (0/1/2/4/8 bits per delta with an all-ones sentinel for a literal byte); version 1 adds per-byte control modes
  (literal, zero) and per-4-byte channel modes (byte deltas, 16-bit deltas, rotated 32-bit XOR). The deltas are
  zigzag-encoded against the previous element; the last element of the tail seeds them.
* ``TRIANGLES`` (index codec, header ``0xe0`` / ``0xe1``): triangle codes with a 16-entry edge FIFO and a 16-entry
  vertex FIFO, free indices as zigzag LEB128 deltas, a 16-byte ``codeaux`` table at the end.
* ``INDICES`` (index sequence, header ``0xd0`` / ``0xd1``): zigzag LEB128 deltas against one of two baselines.
* Filters ``OCTAHEDRAL`` (4/8-byte normals), ``QUATERNION`` (8-byte max-component quaternions), ``EXPONENTIAL``
  (shared-exponent floats), ``COLOR`` (YCoCg colours, ``KHR_meshopt_compression`` only) in float32 arithmetic as
  the reference decoder does.

A malformed stream raises :class:`MeshoptError` (a ``ValueError``) naming what is wrong; nothing reads past the input.
"""

from __future__ import annotations

import numpy as np

MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
FILTERS = ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR")

_BITS_V0 = (0, 2, 4, 8)
_BITS_V1 = ((0, 1, 2, 4), (1, 2, 4, 8))  # by the byte's control mode 0 / 1
# the 16 encoded values of one group, by header bits: 1-bit values least significant bit first, 2- and 4-bit
# values most significant first (vertexcodec.cpp decodeBytesGroup)
_SPLIT = {
    1: [bytes((b >> i) & 1 for i in range(8)) for b in range(256)],
    2: [bytes((b >> s) & 3 for s in (6, 4, 2, 0)) for b in range(256)],
    4: [bytes(((b >> 4) & 15, b & 15)) for b in range(256)],
}
_SENTINELS = {bits: [tuple(m for m, v in enumerate(split[b]) if v == (1 << bits) - 1) for b in range(256)]
              for bits, split in _SPLIT.items()}  # positions of the all-ones values (a literal byte follows)


class MeshoptError(ValueError):
    """A meshopt-compressed stream is malformed or uses a feature this decoder does not know."""


def _decode_groups(data: bytes, p: int, end: int, out: np.ndarray, bits_table: tuple[int, ...]) -> int:
    """Decode ``len(out) / 16`` byte groups starting at ``data[p]`` into ``out`` (uint8); returns the new offset."""
    groups = len(out) // 16
    header_size = (groups + 3) // 4
    if p + header_size > end:
        raise MeshoptError("attribute stream ends inside a group header")
    header = data[p:p + header_size]
    p += header_size
    buf = bytearray(16 * groups)
    for g in range(groups):
        bits = bits_table[(header[g >> 2] >> ((g & 3) << 1)) & 3]
        if bits == 0:
            continue
        base = g * 16
        if bits == 8:
            if p + 16 > end:
                raise MeshoptError("attribute stream ends inside a literal group")
            buf[base:base + 16] = data[p:p + 16]
            p += 16
            continue
        nbytes = 2 * bits  # 16 values of `bits` bits, then one literal byte per all-ones value
        if p + nbytes > end:
            raise MeshoptError("attribute stream ends inside a group")
        split, where = _SPLIT[bits], _SENTINELS[bits]
        per = 8 // bits
        values = bytearray()
        literal: list[int] = []
        for i, b in enumerate(data[p:p + nbytes]):
            values += split[b]
            if where[b]:
                literal.extend(i * per + m for m in where[b])
        p += nbytes
        if literal:
            if p + len(literal) > end:
                raise MeshoptError("attribute stream ends inside a group's literal bytes")
            for m, v in zip(literal, data[p:p + len(literal)], strict=True):
                values[m] = v
            p += len(literal)
        buf[base:base + 16] = values
    out[:] = np.frombuffer(bytes(buf), np.uint8)
    return p


def _unzigzag(v: np.ndarray) -> np.ndarray:
    """Zigzag decoding ``(v >> 1) ^ -(v & 1)`` in ``v``'s unsigned width."""
    return (v >> 1) ^ (np.zeros_like(v) - (v & 1))


def decode_vertex_buffer(data: bytes, count: int, stride: int) -> np.ndarray:
    """``ATTRIBUTES`` mode: ``count`` elements of ``stride`` bytes (``stride % 4 == 0``, <= 256) as (count * stride,)
    uint8."""
    if stride <= 0 or stride > 256 or stride % 4:
        raise MeshoptError(f"ATTRIBUTES byteStride {stride} must be a multiple of 4 in 4..256")
    if len(data) < 1 or data[0] & 0xF0 != 0xA0:
        raise MeshoptError("not a meshopt attribute stream (header byte is not 0xa0/0xa1)")
    version = data[0] & 0x0F
    if version > 1:
        raise MeshoptError(f"meshopt attribute codec version {version} is newer than this decoder (0, 1)")
    tail_size = stride + (0 if version == 0 else stride // 4)
    tail_pad = max(tail_size, 32 if version == 0 else 24)
    if len(data) < 1 + tail_pad:
        raise MeshoptError("attribute stream is shorter than its tail")
    end = len(data) - tail_pad  # where block data must stop
    tail = len(data) - tail_size
    last = np.frombuffer(data, np.uint8, stride, tail).copy()
    channels = data[tail + stride:tail + tail_size] if version else bytes(stride // 4)
    block_size = min((8192 // stride) & ~15, 256)
    out = np.zeros((count, stride), np.uint8)
    p = 1
    for start in range(0, count, block_size):
        n = min(block_size, count - start)
        aligned = (n + 15) & ~15
        control = b""
        if version:
            if p + stride // 4 > end:
                raise MeshoptError("attribute stream ends inside a block's control bytes")
            control = data[p:p + stride // 4]
            p += stride // 4
        deltas = np.zeros((stride, aligned), np.uint8)
        for k in range(stride):
            ctrl = (control[k >> 2] >> ((k & 3) << 1)) & 3 if version else 0
            if ctrl == 3:  # literal bytes
                if p + n > end:
                    raise MeshoptError("attribute stream ends inside literal bytes")
                deltas[k, :n] = np.frombuffer(data, np.uint8, n, p)
                p += n
            elif ctrl == 2:  # all zero
                continue
            else:
                p = _decode_groups(data, p, end, deltas[k], _BITS_V1[ctrl] if version else _BITS_V0)
        d = deltas[:, :n]
        for k in range(0, stride, 4):
            channel = channels[k >> 2]
            mode = channel & 3
            if mode == 0:  # byte deltas
                for j in range(k, k + 4):
                    out[start:start + n, j] = last[j] + np.cumsum(_unzigzag(d[j]), dtype=np.uint8)
            elif mode == 1:  # 16-bit deltas
                for j in (k, k + 2):
                    v = d[j].astype(np.uint16) | (d[j + 1].astype(np.uint16) << 8)
                    prev = np.uint16(int(last[j]) | (int(last[j + 1]) << 8))
                    vals = prev + np.cumsum(_unzigzag(v), dtype=np.uint16)
                    out[start:start + n, j] = (vals & 0xFF).astype(np.uint8)
                    out[start:start + n, j + 1] = (vals >> 8).astype(np.uint8)
            elif mode == 2:  # rotated 32-bit XOR deltas
                v = (d[k].astype(np.uint32) | (d[k + 1].astype(np.uint32) << 8) | (d[k + 2].astype(np.uint32) << 16)
                     | (d[k + 3].astype(np.uint32) << 24))
                rot = np.uint32((32 - (channel >> 4)) & 31)
                if rot:
                    v = (v << rot) | (v >> np.uint32(32 - int(rot)))
                prev = np.uint32(int.from_bytes(bytes(last[k:k + 4]), "little"))
                vals = np.bitwise_xor.accumulate(v) ^ prev
                out[start:start + n, k:k + 4] = vals.astype("<u4").view(np.uint8).reshape(n, 4)
            else:
                raise MeshoptError(f"attribute stream has an invalid channel mode {mode}")
        last = out[start + n - 1].copy()
    if p != end:
        raise MeshoptError(f"attribute stream has {end - p} unexpected bytes before its tail")
    return out.reshape(-1)


def _leb128(data: bytes, p: int, end: int) -> tuple[int, int]:
    n = shift = 0
    while True:
        if p >= end:
            raise MeshoptError("index stream ends inside a varint")
        b = data[p]
        p += 1
        n |= (b & 0x7F) << shift
        if b < 0x80:
            return n, p
        shift += 7
        if shift > 35:
            raise MeshoptError("index stream has an over-long varint")


def _dezig32(v: int) -> int:
    return ((v >> 1) ^ -(v & 1)) & 0xFFFFFFFF


def decode_index_buffer(data: bytes, count: int, index_size: int) -> np.ndarray:
    """``TRIANGLES`` mode: ``count`` (a multiple of 3) triangle-list indices as (count,) uint16/uint32."""
    if count % 3 or index_size not in (2, 4):
        raise MeshoptError(f"TRIANGLES needs a count divisible by 3 and byteStride 2 or 4 (got {count}, {index_size})")
    tris = count // 3
    if len(data) < 1 + tris + 16:
        raise MeshoptError("triangle stream is shorter than one code per triangle and its 16-byte table")
    if data[0] & 0xF0 != 0xE0:
        raise MeshoptError("not a meshopt triangle stream (header byte is not 0xe0/0xe1)")
    version = data[0] & 0x0F
    if version > 1:
        raise MeshoptError(f"meshopt index codec version {version} is newer than this decoder (0, 1)")
    fecmax = 13 if version >= 1 else 15
    edge_a, edge_b = [0xFFFFFFFF] * 16, [0xFFFFFFFF] * 16  # as the reference decoder's memset(-1)
    vfifo = [0xFFFFFFFF] * 16
    eo = vo = 0
    nxt = last = 0
    end = len(data) - 16
    aux = data[end:]
    out = np.empty(count, np.uint32)
    code_p, p = 1, 1 + tris
    mask = 0xFFFFFFFF
    for t in range(tris):
        code = data[code_p]
        code_p += 1
        if code < 0xF0:
            fe = code >> 4
            a = edge_a[(eo - 1 - fe) & 15]
            b = edge_b[(eo - 1 - fe) & 15]
            fec = code & 15
            if fec < fecmax:
                if fec == 0:
                    c = nxt
                    nxt += 1
                    vfifo[vo] = c
                    vo = (vo + 1) & 15
                else:
                    c = vfifo[(vo - 1 - fec) & 15]
            else:
                if fec != 15:
                    c = (last + (fec * 2 - 27)) & mask
                else:
                    v, p = _leb128(data, p, end)
                    c = (last + _dezig32(v)) & mask
                last = c
                vfifo[vo] = c
                vo = (vo + 1) & 15
            edge_a[eo], edge_b[eo] = c, b
            eo = (eo + 1) & 15
            edge_a[eo], edge_b[eo] = a, c
            eo = (eo + 1) & 15
        else:
            if code < 0xFE:
                codeaux = aux[code & 15]
                feb, fec = codeaux >> 4, codeaux & 15
                a = nxt
                nxt += 1
                if feb == 0:
                    b = nxt
                    nxt += 1
                else:
                    b = vfifo[(vo - feb) & 15]
                if fec == 0:
                    c = nxt
                    nxt += 1
                else:
                    c = vfifo[(vo - fec) & 15]
                pushes = [a] + ([b] if feb == 0 else []) + ([c] if fec == 0 else [])
            else:
                if p >= end:
                    raise MeshoptError("triangle stream ends inside a code")
                codeaux = data[p]
                p += 1
                fea = 0 if code == 0xFE else 15
                feb, fec = codeaux >> 4, codeaux & 15
                if codeaux == 0:
                    nxt = 0
                a = b = c = 0
                if fea == 0:
                    a = nxt
                    nxt += 1
                if feb == 0:
                    b = nxt
                    nxt += 1
                elif feb != 15:
                    b = vfifo[(vo - feb) & 15]
                if fec == 0:
                    c = nxt
                    nxt += 1
                elif fec != 15:
                    c = vfifo[(vo - fec) & 15]
                if fea == 15:
                    v, p = _leb128(data, p, end)
                    last = a = (last + _dezig32(v)) & mask
                if feb == 15:
                    v, p = _leb128(data, p, end)
                    last = b = (last + _dezig32(v)) & mask
                if fec == 15:
                    v, p = _leb128(data, p, end)
                    last = c = (last + _dezig32(v)) & mask
                pushes = [a] + ([b] if feb in (0, 15) else []) + ([c] if fec in (0, 15) else [])
            for v in pushes:
                vfifo[vo] = v
                vo = (vo + 1) & 15
            for e0, e1 in ((b, a), (c, b), (a, c)):
                edge_a[eo], edge_b[eo] = e0, e1
                eo = (eo + 1) & 15
        out[3 * t:3 * t + 3] = (a & mask, b & mask, c & mask)
    if p != end:
        raise MeshoptError(f"triangle stream has {end - p} unexpected bytes before its table")
    return out.astype(np.uint16) if index_size == 2 else out


def decode_index_sequence(data: bytes, count: int, index_size: int) -> np.ndarray:
    """``INDICES`` mode: ``count`` indices as (count,) uint16/uint32."""
    if index_size not in (2, 4):
        raise MeshoptError(f"INDICES needs byteStride 2 or 4 (got {index_size})")
    if len(data) < 1 + 4 or data[0] & 0xF0 != 0xD0:
        raise MeshoptError("not a meshopt index sequence (header byte is not 0xd0/0xd1)")
    if data[0] & 0x0F > 1:
        raise MeshoptError(f"meshopt index sequence version {data[0] & 0x0F} is newer than this decoder (0, 1)")
    end = len(data) - 4  # a 4-byte tail
    base = [0, 0]
    out = np.empty(count, np.uint32)
    p = 1
    for i in range(count):
        v, p = _leb128(data, p, end)
        b = v & 1
        base[b] = (base[b] + _dezig32(v >> 1)) & 0xFFFFFFFF
        out[i] = base[b]
    if p != end:
        raise MeshoptError(f"index sequence has {end - p} unexpected bytes before its tail")
    return out.astype(np.uint16) if index_size == 2 else out


def _round(x: np.ndarray) -> np.ndarray:
    """Round float32 to the nearest integer, ties to even: the reference SIMD / WebAssembly decoders' ``x + 1.5 *
    2**23`` snap (the JavaScript ``MeshoptDecoder`` every web viewer uses; its scalar C++ fallback rounds ties away
    from zero, a one-unit difference on exact ties)."""
    return np.rint(x)


def filter_octahedral(raw: np.ndarray, stride: int) -> np.ndarray:
    """``OCTAHEDRAL`` filter on (count * stride,) uint8: int8 (stride 4) or int16 (stride 8) unit vectors, w kept."""
    if stride not in (4, 8):
        raise MeshoptError(f"OCTAHEDRAL filter needs byteStride 4 or 8 (got {stride})")
    itype = np.int8 if stride == 4 else np.int16
    q = raw.view(itype).reshape(-1, 4)
    f = q[:, :3].astype(np.float32)
    x, y = f[:, 0], f[:, 1]
    z = f[:, 2] - np.abs(x) - np.abs(y)
    t = np.minimum(z, np.float32(0))
    x = x + np.where(x >= 0, t, -t)
    y = y + np.where(y >= 0, t, -t)
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.float32(np.iinfo(itype).max) / np.sqrt(x * x + (y * y + z * z))
        res = np.stack([_round(x * s), _round(y * s), _round(z * s)], axis=1)
    q = q.copy()
    q[:, :3] = np.nan_to_num(res).astype(np.int32).astype(itype)
    return q.reshape(-1).view(np.uint8)


def filter_quaternion(raw: np.ndarray, stride: int) -> np.ndarray:
    """``QUATERNION`` filter on (count * 8,) uint8: max-component int16 quaternions to normalized int16 (x, y, z, w)."""
    if stride != 8:
        raise MeshoptError(f"QUATERNION filter needs byteStride 8 (got {stride})")
    q = raw.view(np.int16).reshape(-1, 4)
    sf = (q[:, 3].astype(np.int32) | 3).astype(np.float32)
    x, y, z = (q[:, i].astype(np.float32) for i in range(3))
    ws = sf * sf
    ww = (ws + ws) - (x * x + (y * y + z * z))
    w = np.sqrt(np.maximum(ww, np.float32(0)))
    ss = np.float32(32767) / np.sqrt(np.float32(2)) / sf
    xf, yf, zf, wf = _round(x * ss), _round(y * ss), _round(z * ss), _round(w * ss)
    qc = (q[:, 3] & 3).astype(np.int64)
    out = np.empty_like(q)
    rows = np.arange(len(q))
    for vals, shift in ((xf, 1), (yf, 2), (zf, 3), (wf, 0)):
        out[rows, (qc + shift) & 3] = vals.astype(np.int32).astype(np.int16)
    return out.reshape(-1).view(np.uint8)


def filter_exponential(raw: np.ndarray, stride: int) -> np.ndarray:
    """``EXPONENTIAL`` filter on (count * stride,) uint8: (8-bit exponent, 24-bit mantissa) int32s to float32."""
    if stride % 4:
        raise MeshoptError(f"EXPONENTIAL filter needs a byteStride divisible by 4 (got {stride})")
    v = raw.view("<i4")
    m = (v << 8) >> 8
    e = v >> 24
    with np.errstate(over="ignore"):
        f = (((e + 127).astype(np.uint32) << 23).view(np.float32)) * m.astype(np.float32)
    return f.astype("<f4").view(np.uint8)


def filter_color(raw: np.ndarray, stride: int) -> np.ndarray:
    """``COLOR`` filter on (count * stride,) uint8: YCoCg (stride 4: 8-bit, 8: 16-bit) to RGBA unsigned normalized."""
    if stride not in (4, 8):
        raise MeshoptError(f"COLOR filter needs byteStride 4 or 8 (got {stride})")
    utype, stype = (np.uint8, np.int8) if stride == 4 else (np.uint16, np.int16)
    u = raw.view(utype).reshape(-1, 4)
    s = raw.view(stype).reshape(-1, 4)
    a_in = u[:, 3].astype(np.int32)
    as_ = a_in.copy()
    for sh in (1, 2, 4, 8):
        as_ |= as_ >> sh
    y = u[:, 0].astype(np.int32)
    co, cg = s[:, 1].astype(np.int32), s[:, 2].astype(np.int32)
    r, g, b = y + co - cg, y + cg, y - co - cg
    a = ((a_in << 1) & as_) | (a_in & 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ss = np.float32(np.iinfo(utype).max) / as_.astype(np.float32)
    out = np.stack([_round(c.astype(np.float32) * ss) for c in (r, g, b, a)], axis=1)
    out = np.nan_to_num(out, posinf=0.0, neginf=0.0).astype(np.int64).astype(utype)
    return out.reshape(-1).view(np.uint8)


_FILTERS = {"OCTAHEDRAL": filter_octahedral, "QUATERNION": filter_quaternion, "EXPONENTIAL": filter_exponential,
            "COLOR": filter_color}


def decode_gltf_buffer(data: bytes, count: int, stride: int, mode: str, filter: str = "NONE") -> bytes:
    """Decode one compressed bufferView: ``count`` elements of ``stride`` bytes in ``mode`` (:data:`MODES`), then
    ``filter`` (:data:`FILTERS`, ``ATTRIBUTES`` only); returns ``count * stride`` bytes."""
    if mode not in MODES:
        raise MeshoptError(f"unknown meshopt mode {str(mode)[:40]!r} (expected one of {', '.join(MODES)})")
    if filter not in FILTERS:
        raise MeshoptError(f"unknown meshopt filter {str(filter)[:40]!r} (expected one of {', '.join(FILTERS)})")
    if mode != "ATTRIBUTES" and filter != "NONE":
        raise MeshoptError(f"meshopt mode {mode} takes no filter (got {filter})")
    if mode == "TRIANGLES":
        return decode_index_buffer(data, count, stride).astype(f"<u{stride}").tobytes()
    if mode == "INDICES":
        return decode_index_sequence(data, count, stride).astype(f"<u{stride}").tobytes()
    raw = decode_vertex_buffer(data, count, stride)
    if filter != "NONE":
        raw = _FILTERS[filter](raw, stride)
    return raw.tobytes()
