"""Media type of the texture images a mesh may carry: PNG, JPEG and WebP (what glTF
embeds, the last through EXT_texture_webp, and what browsers decode)."""

from __future__ import annotations

__all__ = ["IMAGE_SUFFIXES", "image_media_type"]

# Media type -> the file name suffix an image of it gets (OBJ companions, exports).
IMAGE_SUFFIXES = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp"}


def image_media_type(data: bytes) -> str | None:
    """ "image/png", "image/jpeg" or "image/webp" from the image's magic bytes, else
    None."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if data[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "image/webp"
    return None
