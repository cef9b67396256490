"""Media type of the texture images a mesh may carry."""

from __future__ import annotations


def image_media_type(data: bytes) -> str | None:
    """ "image/png" or "image/jpeg" from the image's magic bytes, else None."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if data[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    return None
