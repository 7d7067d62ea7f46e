"""PTP (ISO 15740 / PIMA 15740) codes and the USB still-image container format.

A bulk container is ``length:u32 type:u16 code:u16 transaction_id:u32`` then the payload
(command/response/event parameters as u32, or the data phase), all little-endian. Types:
1 command, 2 data, 3 response, 4 event. Strings are ``n:u8`` UCS-2 characters including a
terminating NUL (``n = 0`` for the empty string); arrays are ``count:u32`` then elements.

References
----------
ISO 15740:2013 (PTP) §5 (datatypes), §10 (operations), §11 (responses), §12 (events),
§13 (device properties); USB Still Image Capture Device Definition 1.0, §7 (containers).
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

__all__ = [
    "CONTAINER_COMMAND",
    "CONTAINER_DATA",
    "CONTAINER_EVENT",
    "CONTAINER_RESPONSE",
    "EV",
    "OP",
    "PROP",
    "RC",
    "container",
    "pack_array",
    "pack_string",
    "parse_container",
    "unpack_array",
    "unpack_string",
]

CONTAINER_COMMAND, CONTAINER_DATA, CONTAINER_RESPONSE, CONTAINER_EVENT = 1, 2, 3, 4

OP = {
    "GetDeviceInfo": 0x1001,
    "OpenSession": 0x1002,
    "CloseSession": 0x1003,
    "GetStorageIDs": 0x1004,
    "GetObjectHandles": 0x1007,
    "GetObjectInfo": 0x1008,
    "GetObject": 0x1009,
    "DeleteObject": 0x100B,
    "InitiateCapture": 0x100E,
    "GetDevicePropDesc": 0x1014,
    "GetDevicePropValue": 0x1015,
    "SetDevicePropValue": 0x1016,
}
RC = {
    "OK": 0x2001,
    "GeneralError": 0x2002,
    "SessionNotOpen": 0x2003,
    "InvalidTransactionID": 0x2004,
    "OperationNotSupported": 0x2005,
    "ParameterNotSupported": 0x2006,
    "IncompleteTransfer": 0x2007,
    "InvalidStorageID": 0x2008,
    "InvalidObjectHandle": 0x2009,
    "DevicePropNotSupported": 0x200A,
    "DeviceBusy": 0x2019,
    "InvalidDevicePropValue": 0x201C,
    "InvalidParameter": 0x201D,
    "SessionAlreadyOpen": 0x201E,
}
EV = {"ObjectAdded": 0x4002, "CaptureComplete": 0x400D}
PROP = {"FNumber": 0x5007, "ExposureTime": 0x500D}
FORMAT_TIFF = 0x380D
RC_NAMES = {v: k for k, v in RC.items()}
OP_NAMES = {v: k for k, v in OP.items()}


def container(
    ctype: int, code: int, tid: int, params: Sequence[int] = (), payload: bytes = b""
) -> bytes:
    """One bulk container: header, u32 parameters, then ``payload``."""
    body = b"".join(struct.pack("<I", int(p) & 0xFFFFFFFF) for p in params) + bytes(payload)
    return struct.pack("<IHHI", 12 + len(body), ctype, code, tid & 0xFFFFFFFF) + body


def parse_container(data: bytes) -> tuple[int, int, int, bytes]:
    """``(type, code, transaction_id, payload)``; ``ValueError`` if malformed."""
    if len(data) < 12:
        raise ValueError(f"container of {len(data)} bytes: expected at least 12")
    length, ctype, code, tid = struct.unpack_from("<IHHI", data)
    if length != len(data):
        raise ValueError(f"container length field {length} but {len(data)} bytes received")
    if ctype not in (1, 2, 3, 4):
        raise ValueError(f"container type {ctype}: expected 1-4")
    return ctype, code, tid, bytes(data[12:])


def pack_string(s: str) -> bytes:
    if not s:
        return b"\x00"
    enc = (s + "\x00").encode("utf-16-le")
    return bytes([len(s) + 1]) + enc


def unpack_string(buf: bytes, off: int) -> tuple[str, int]:
    n = buf[off]
    off += 1
    if n == 0:
        return "", off
    s = buf[off : off + 2 * n].decode("utf-16-le").rstrip("\x00")
    return s, off + 2 * n


def pack_array(fmt: str, values: Sequence[int]) -> bytes:
    return struct.pack("<I", len(values)) + b"".join(struct.pack("<" + fmt, v) for v in values)


def unpack_array(fmt: str, buf: bytes, off: int) -> tuple[list[int], int]:
    (n,) = struct.unpack_from("<I", buf, off)
    off += 4
    size = struct.calcsize("<" + fmt)
    vals = [struct.unpack_from("<" + fmt, buf, off + i * size)[0] for i in range(n)]
    return vals, off + n * size
