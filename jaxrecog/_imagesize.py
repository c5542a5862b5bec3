"""An image file's width and height from its header only, before it is
decoded: a 20000 x 20000 PNG of a few kB would take 1.2 GB (and many
seconds) to decode, so :mod:`jaxrecog.dbformat` checks the size first.
PNG (IHDR), JPEG (the first SOFn), BMP and PGM/PPM are read here; other
formats through Pillow's lazy open where Pillow is installed.  A leaf module
of the core (standard library, Pillow optional)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["MAX_IMAGE_PIXELS", "image_size"]

#: The most pixels one database image may have (2**25: e.g. 5792 x 5792),
#: checked from the file's header before it is decoded.
MAX_IMAGE_PIXELS = 1 << 25


def _be(b: bytes) -> int:
    return int.from_bytes(b, "big")


def _jpeg_size(f) -> tuple[int, int] | None:
    """(width, height) from a JPEG's first frame header (SOFn), or None."""
    f.seek(2)
    for _ in range(10_000):
        b = f.read(1)
        while b and b != b"\xff":
            b = f.read(1)
        while b == b"\xff":
            b = f.read(1)
        if not b:
            return None
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:
            continue  # markers without a length
        n = f.read(2)
        if len(n) < 2:
            return None
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            sof = f.read(5)
            return (_be(sof[3:5]), _be(sof[1:3])) if len(sof) == 5 else None
        f.seek(_be(n) - 2, 1)
    return None


def _pnm_size(f) -> tuple[int, int] | None:
    """(width, height) from a PGM/PPM/PBM header, or None."""
    text = f.read(1024).split(b"\n")
    nums: list[int] = []
    for line in text[0:]:
        for tok in line.split(b"#")[0].split():
            if tok.isdigit():
                nums.append(int(tok))
            if len(nums) == 2:
                return nums[0], nums[1]
    return None


def image_size(file: Path) -> tuple[int, int] | None:
    """(width, height) of an image file read from its header only (PNG IHDR,
    JPEG SOF, BMP, PGM/PPM; other formats through Pillow's lazy open where
    Pillow is installed), or None when the header does not say."""
    with open(file, "rb") as f:
        head = f.read(26)
        if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
            return _be(head[16:20]), _be(head[20:24])
        if head[:2] == b"\xff\xd8":
            return _jpeg_size(f)
        if head[:2] == b"BM" and len(head) >= 26:
            return (int.from_bytes(head[18:22], "little", signed=True),
                    abs(int.from_bytes(head[22:26], "little", signed=True)))
        if head[:1] == b"P" and head[1:2] in b"123456":
            f.seek(2)
            return _pnm_size(f)
    try:
        from PIL import Image
    except ImportError:
        return None
    try:
        with Image.open(file) as im:  # reads the header only
            return tuple(im.size)
    except Exception:  # noqa: BLE001 - not an image Pillow knows: OpenCV's decoder decides
        return None
