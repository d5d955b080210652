"""PNG, the one image codec of hub-envs' datasets: a fast vectorised encoder and OpenCV/PIL decoding.

Frames are stored inside the data parquet as ``datasets.Image`` structs holding PNG bytes (LeRobot's
``embed_images`` layout). Encoding uses filter "Up" + zlib level 1 (~6x faster than PIL at level 6, same
pixels); decoding uses OpenCV (LeRobot's dependency; ~4x faster than PIL, releases the GIL) and falls back
to PIL.

    >>> import numpy as np
    >>> img = np.arange(48, dtype=np.uint8).reshape(1, 4, 4, 3)
    >>> bool((decode_png(encode_png(img)[0]) == img[0]).all())
    True
"""

from __future__ import annotations

import functools
import io
import struct
import zlib

import numpy as np

__all__ = ["encode_png", "decode_png", "PNG_CHANNELS"]

# --- encode ------------------------------------------------------------------------------------

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_IEND = struct.pack(">I", 0) + b"IEND" + struct.pack(">I", zlib.crc32(b"IEND"))
_PNG_COLOR_TYPE = {1: 0, 2: 4, 3: 2, 4: 6}  # channels -> gray, gray+alpha, RGB, RGBA
_IDAT_CRC = zlib.crc32(b"IDAT")
_U32 = struct.Struct(">I").pack
#: The channel counts a PNG frame can have.
PNG_CHANNELS = frozenset(_PNG_COLOR_TYPE)


def _png_chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(data, zlib.crc32(tag)))


def encode_png(frames: np.ndarray, level: int = 1) -> list[bytes]:
    """PNG bytes for each ``(H, W, C)`` uint8 frame of ``frames`` (T, H, W, C), C in 1..4.

    Every row uses PNG filter 2 ("Up", computed for all frames at once) and zlib at ``level``;
    any PNG decoder (PIL, which LeRobot uses) returns the exact pixels.

    >>> import io, PIL.Image
    >>> img = np.arange(48, dtype=np.uint8).reshape(1, 4, 4, 3)
    >>> bool((np.asarray(PIL.Image.open(io.BytesIO(encode_png(img)[0]))) == img[0]).all())
    True
    """
    if frames.dtype != np.uint8 or frames.ndim != 4 or frames.shape[-1] not in _PNG_COLOR_TYPE:
        raise ValueError(f"encode_png needs uint8 frames (T, H, W, C) with C in 1..4, got {frames.dtype} {frames.shape}")
    t, h, w, c = frames.shape
    header = _PNG_SIGNATURE + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, _PNG_COLOR_TYPE[c], 0, 0, 0))
    rows = frames.reshape(t, h, w * c)
    filtered = np.empty((t, h, w * c + 1), dtype=np.uint8)
    filtered[:, :, 0] = 2  # "Up": byte minus the byte above (mod 256)
    filtered[:, 0, 1:] = rows[:, 0]
    np.subtract(rows[:, 1:], rows[:, :-1], out=filtered[:, 1:, 1:])
    compress, crc32, u32 = zlib.compress, zlib.crc32, _U32
    out = []
    for frame in filtered:  # one zlib stream per frame: each PNG stands alone
        data = compress(frame, level)
        out.append(b"".join((header, u32(len(data)), b"IDAT", data, u32(crc32(data, _IDAT_CRC)), _PNG_IEND)))
    return out


@functools.cache
def _opencv():
    """OpenCV, imported on the first decode (LeRobot depends on it); None where it is not installed."""
    try:
        import cv2  # heavy: opencv (tens of milliseconds): not for a load that decodes no frame
    except ImportError:  # pragma: no cover
        return None
    return cv2


def decode_png(data: bytes) -> np.ndarray:
    """PNG bytes -> uint8 ``(H, W, C)`` RGB(A) (grayscale gets ``C = 1``), as PIL (LeRobot's decoder) returns them."""
    img = None
    _cv2 = _opencv()
    if _cv2 is not None:
        img = _cv2.imdecode(np.frombuffer(data, np.uint8), _cv2.IMREAD_UNCHANGED)
        if img is not None and img.dtype == np.uint8:
            if img.ndim == 3 and img.shape[2] == 3:
                img = _cv2.cvtColor(img, _cv2.COLOR_BGR2RGB)
            elif img.ndim == 3 and img.shape[2] == 4 and len(data) > 25 and data[25] == 4:  # IHDR colour type 4
                img = np.ascontiguousarray(img[..., [0, 3]])  # gray + alpha, which OpenCV expands to BGRA (B = G = R)
            elif img.ndim == 3 and img.shape[2] == 4:
                img = _cv2.cvtColor(img, _cv2.COLOR_BGRA2RGBA)
        else:
            img = None
    if img is None:
        import PIL.Image  # heavy: pillow

        with PIL.Image.open(io.BytesIO(data)) as pil:
            img = np.asarray(pil)
    return img[..., None] if img.ndim == 2 else img


def decode_pngs(data: list[bytes], shape: tuple[int, ...]) -> np.ndarray:
    """A column of PNG frames -> uint8 ``(T, *shape)`` (``(0, *shape)`` for no frames)."""
    return np.stack([decode_png(b) for b in data]) if data else np.zeros((0, *shape), np.uint8)
