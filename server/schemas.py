"""Request and response models of the HTTP API (version 1)."""

from __future__ import annotations

import dataclasses
import typing
from datetime import UTC, datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

from qem_core import BuildOptions
from qem_core.options import NUMBER_RANGES

from .storage import MeshRecord

__all__ = [
    "FILE_NAME_PATTERN",
    "UPLOAD_EXTENSIONS",
    "LOD_FORMATS",
    "Health",
    "MeshInfo",
    "MeshList",
    "UploadAccepted",
    "UploadParams",
    "mesh_info",
]

# The extensions an upload's name may end in (any case); a name without a dot after its
# last slash is accepted too, its format then guessed from the content.
UPLOAD_EXTENSIONS = ("ply", "obj", "stl", "off", "glb", "gltf", "zip")


def _any_case(word: str) -> str:
    return "".join(f"[{c.lower()}{c.upper()}]" for c in word)


# The rule as a pattern both the OpenAPI document and the server apply (ECMA and Python
# regular expressions agree on it: no flags, no lookaround).
FILE_NAME_PATTERN = (
    r"^(?:.*[/\\])?(?:[^/\\.]*|[^/\\]*\.(?:"
    + "|".join(map(_any_case, UPLOAD_EXTENSIONS))
    + r")[ ]*)$"  # trailing spaces are stripped from the name kept
)

LodFormat = Literal["ply", "obj", "glb", "msgpack", "zip"]
LOD_FORMATS: tuple[str, ...] = typing.get_args(LodFormat)


class MeshInfo(BaseModel):
    """What the server knows about one mesh."""

    id: str = Field(examples=["3f2a9c01d4e5b6a7"])
    name: str = Field(description="file name of the upload", examples=["bunny.ply"])
    status: Literal["queued", "building", "ready", "failed"]
    progress: float = Field(ge=0.0, le=1.0, description="build progress, 1 when ready")
    vertices: int | None = Field(None, description="vertex count of the full mesh")
    faces: int | None = Field(None, description="face count of the full mesh")
    min_vertices: int | None = Field(None, description="vertex count of the base mesh")
    bbox: list[list[float]] | None = Field(
        None, description="[[xmin, ymin, zmin], [xmax, ymax, zmax]]"
    )
    error: str | None = Field(None, description="why the build failed, when failed")
    attempts: int = Field(description="build attempts started")
    options: dict[str, Any] = Field(description="build options given at upload")
    size_bytes: int = Field(description="size of the uploaded file")
    created_at: datetime
    updated_at: datetime


class MeshList(BaseModel):
    meshes: list[MeshInfo]


class UploadAccepted(BaseModel):
    id: str = Field(examples=["3f2a9c01d4e5b6a7"])
    status: Literal["queued"] = "queued"
    url: str = Field(description="where to follow the build", examples=["/v1/meshes/3f2a..."])


class Health(BaseModel):
    status: Literal["ok"] = "ok"
    version: str


def _upload_param_fields() -> dict[str, Any]:
    # One query parameter per BuildOptions field, so the API follows qem_core's options.
    hints = typing.get_type_hints(BuildOptions)
    fields: dict[str, Any] = {
        "name": (
            str | None,
            Field(
                None,
                max_length=255,
                # Documented, and checked by uploads.check_file_name (a 415 that says
                # what to do, rather than a 422 quoting the pattern).
                json_schema_extra={"pattern": FILE_NAME_PATTERN},
                description="file name of a raw-body upload (its extension gives the "
                "format: .ply .obj .stl .off .glb .zip, any case; a name without a dot is "
                "guessed from the content); overrides the multipart file name",
            ),
        )
    }
    # Ranges documented; BuildOptions checks them (its message names the option's range).
    ranges = {name: {"minimum": low, "maximum": high} for name, low, high in NUMBER_RANGES}
    for option in dataclasses.fields(BuildOptions):
        fields[option.name] = (
            hints[option.name] | None,
            Field(
                None,
                description=f"build option (default {option.default!r})",
                json_schema_extra=ranges.get(option.name),
            ),
        )
    return fields


UploadParams = create_model(
    "UploadParams",
    __config__=ConfigDict(extra="forbid"),
    __doc__="Query parameters of an upload: the file name and build options.",
    **_upload_param_fields(),
)


def upload_options(params: BaseModel) -> dict[str, Any]:
    """The build options given explicitly in `params`."""
    return {
        name: value
        for name, value in params.model_dump(exclude_none=True).items()
        if name != "name"
    }


def _time(seconds: float) -> datetime:
    return datetime.fromtimestamp(seconds, tz=UTC)


def mesh_info(record: MeshRecord) -> MeshInfo:
    return MeshInfo(
        id=record.id,
        name=record.name,
        status=record.status,
        progress=record.progress,
        vertices=record.n_vertices,
        faces=record.n_faces,
        min_vertices=record.n_base,
        bbox=None if record.bbox is None else [list(corner) for corner in record.bbox],
        error=record.error,
        attempts=record.attempts,
        options=record.options,
        size_bytes=record.upload_bytes,
        created_at=_time(record.created_at),
        updated_at=_time(record.updated_at),
    )
