"""Wire format of the robot server: msgpack maps, numpy arrays as msgpack extension type 1.

Request: ``{"op": str, "id": int, "client": str, "token": str, "args": {...}}`` (``token``: the secret a
claim answered, for the owner's operations; "" otherwise).
Reply: ``{"id": int, "ok": True, "result": ...}`` or ``{"id": int, "ok": False, "error": {"type": str,
"message": str}}``. An array travels as ``ExtType(1, msgpack([dtype.str, shape, raw bytes]))``; only
plain numeric / bool dtypes are accepted (never object arrays).
"""

from __future__ import annotations

from typing import Any

import msgpack
import numpy as np

from unilab_jax.robots import interface

ARRAY_EXT = 1
ALLOWED_DTYPES = frozenset(np.dtype(t).str for t in ("u1", "i4", "i8", "f4", "f8", "?"))
# Errors a reply may name; anything else arrives as RobotError with the original type in the message.
ERRORS: dict[str, type[Exception]] = {
    cls.__name__: cls for cls in (interface.RobotError, interface.RobotDisconnected, interface.RobotEstopped,
                                  interface.RobotClaimed, interface.RobotFaulted, interface.BadRequest)
}
ERRORS["ValueError"] = ValueError


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        if obj.dtype.str not in ALLOWED_DTYPES:
            raise TypeError(f"cannot send arrays of dtype {obj.dtype}")
        a = np.ascontiguousarray(obj)
        return msgpack.ExtType(ARRAY_EXT, msgpack.packb([a.dtype.str, list(a.shape), a.tobytes()]))
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot send objects of type {type(obj).__name__}")


def _ext_hook(code: int, data: bytes) -> Any:
    if code != ARRAY_EXT:
        raise interface.BadRequest(f"unknown msgpack extension type {code}")
    dtype, shape, raw = msgpack.unpackb(data)
    if dtype not in ALLOWED_DTYPES:
        raise interface.BadRequest(f"array dtype {dtype!r} not allowed; allowed: {sorted(ALLOWED_DTYPES)}")
    if not isinstance(shape, list) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise interface.BadRequest(f"bad array shape {shape!r}")
    count = int(np.prod(shape)) if shape else 1
    if count * np.dtype(dtype).itemsize != len(raw):
        raise interface.BadRequest(f"array of shape {shape} and dtype {dtype} does not match {len(raw)} bytes")
    return np.frombuffer(raw, dtype=dtype).reshape(shape).copy()


def pack(obj: Any) -> bytes:
    """Any tree of dicts / lists / scalars / numpy arrays -> bytes."""
    return msgpack.packb(obj, default=_default, use_bin_type=True)


def unpack(data: bytes) -> Any:
    """bytes -> the packed tree; raises BadRequest on anything that is not a valid message."""
    try:
        return msgpack.unpackb(data, ext_hook=_ext_hook, raw=False, strict_map_key=True)
    except interface.BadRequest:
        raise
    except Exception as e:  # noqa: BLE001  (msgpack raises several unrelated types)
        raise interface.BadRequest(f"undecodable message ({type(e).__name__}: {e})") from None


def request(op: str, req_id: int, client: str, args: dict[str, Any] | None = None, token: str = "") -> bytes:
    return pack({"op": op, "id": req_id, "client": client, "token": token, "args": args or {}})


def parse_request(msg: Any) -> tuple[str, int, str, str, dict[str, Any]]:
    """Validates an unpacked request; returns (op, id, client, token, args) or raises BadRequest."""
    if not isinstance(msg, dict):
        raise interface.BadRequest(f"a request must be a map, got {type(msg).__name__}")
    op, req_id, client, args = msg.get("op"), msg.get("id"), msg.get("client"), msg.get("args", {})
    token = msg.get("token", "")
    id_ok = isinstance(req_id, int) and not isinstance(req_id, bool)
    if not isinstance(op, str) or not id_ok or not isinstance(client, str) or not client or not isinstance(token, str):
        raise interface.BadRequest("a request needs op (str), id (int), a non-empty client (str) and token (str)")
    if not isinstance(args, dict):
        raise interface.BadRequest(f"args must be a map, got {type(args).__name__}")
    return op, req_id, client, token, args


def ok(req_id: int, result: Any) -> bytes:
    return pack({"id": req_id, "ok": True, "result": result})


def error(req_id: int, exc: BaseException) -> bytes:
    return pack({"id": req_id, "ok": False, "error": {"type": type(exc).__name__, "message": str(exc)}})


def raise_error(err: dict[str, Any]) -> None:
    """Re-raises an error reply's exception on the client side."""
    cls = ERRORS.get(err.get("type", ""))
    message = str(err.get("message", ""))
    if cls is None:
        raise interface.RobotError(f"{err.get('type')}: {message}")
    raise cls(message)
