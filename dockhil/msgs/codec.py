"""Encode and decode messages: msgpack bytes, typed validation on decode.

The bytes are plain msgpack maps (field name -> value), readable by any
msgpack library. Decoding checks every field's type and refuses NaN/Inf in
physical fields; the error names the field and the reason.
"""

from __future__ import annotations

import functools
import re
from typing import TypeVar

import msgspec

from dockhil.msgs import Header

T = TypeVar("T", bound=msgspec.Struct)

_encoder = msgspec.msgpack.Encoder()
encode = _encoder.encode


class DecodeError(ValueError):
    """Bytes that are not a valid message of the expected type."""


@functools.cache
def _decoder(cls: type) -> msgspec.msgpack.Decoder:
    return msgspec.msgpack.Decoder(cls)


_BOUND = re.compile(r"Expected `float` [<>]= [-0-9.e+]+")


def decode(buf: bytes, cls: type[T]) -> T:
    """Decode `buf` as a `cls`; raise DecodeError naming the field and reason."""
    try:
        return _decoder(cls).decode(buf)
    except msgspec.ValidationError as exc:
        text = str(exc)
        # msgspec reports NaN/Inf as a failed bound; say what it is.
        if "1.7976931348623157e+308" in text:
            text = _BOUND.sub("NaN or Inf refused (physical fields must be finite)", text)
        elif "Expected `float` >= 0.0" in text:
            text = text.replace("Expected `float` >= 0.0", "negative or NaN value refused (must be >= 0)")
        raise DecodeError(f"{cls.__name__}: {text}") from None
    except msgspec.DecodeError as exc:
        raise DecodeError(f"{cls.__name__}: not msgpack ({exc})") from None
    except UnicodeDecodeError as exc:  # a map key or string that is not UTF-8
        raise DecodeError(f"{cls.__name__}: a string is not valid UTF-8 ({exc.reason} at byte {exc.start})") from None


class _Headed(msgspec.Struct):
    """Only the header of any message: the rest of the map is skipped, not validated."""

    header: Header


_header_decoder = msgspec.msgpack.Decoder(_Headed)


def decode_header(buf: bytes) -> Header | None:
    """The header of any dockhil message (nothing else checked), or None where none can be read."""
    try:
        return _header_decoder.decode(buf).header
    except (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError):
        return None


def schema(cls: type) -> dict:
    """JSON Schema of a message type (embedded in bags)."""
    return msgspec.json.schema(cls)
